"""The simulated cell (a true robot with its own kinematics and errors, spheres, tracker,
renderer) and fake backends / protocol peers for every driver."""
