"""The FANUC M-710iC/50's joint limits, joint speeds and the cell's home position as plain
numbers: calib/robot.py (the data sheet, with the geometry) makes its arrays from them, and the
cell file's defaults read them here without loading numpy (a command that only reads its
settings, `rvis status`, starts fast)."""

from __future__ import annotations

#: Controller joint limits [deg], J1..J6 (J3 from the horizon, as the pendant enforces it).
JOINT_LOWER_DEG = (-180.0, -90.0, -160.0, -360.0, -125.0, -360.0)
JOINT_UPPER_DEG = (180.0, 135.0, 280.0, 360.0, 125.0, 360.0)

#: Maximum joint speeds [deg/s] (mechanical manual via ROS-I).
JOINT_SPEED_DEG_S = (175.0, 175.0, 175.0, 250.0, 250.0, 355.0)

#: The service's home position [deg], controller angles: the sensor looking down, clear of the
#: car body; every window starts and ends there.
HOME_DEG = (0.0, 0.0, 0.0, 0.0, -90.0, 0.0)

#: Pose repeatability RP [mm] per ISO 9283, FANUC's data sheet of the M-710iC series
#: ("Repeatability +-0.07 mm"); the simulated world's true robot repeats by the same figure
#: (fakes/truth.py `M710IC50_RP_MM`, which may not import this package).
POSE_REPEATABILITY_MM = 0.07

#: Reach [mm] of the M-710iC/50 (FANUC's data sheet: 2050 mm, J1 axis to the wrist centre):
#: a body feature whose nominal lies further from the base frame's origin is outside the
#: workspace.
REACH_MM = 2050.0
