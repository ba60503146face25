"""Device interfaces (camera, galvo, robot, tracker, PLC) and their real backends, selected by
URL. Drivers move joints and grab frames; they know no kinematics (no calib/, vision/, app/)."""
