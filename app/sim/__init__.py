"""The simulated cell's sessions: the in-line service on the simulated line (`rvis run --sim`)."""
