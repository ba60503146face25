"""FANUC X Y Z W P R poses and the URDF roll-pitch-yaw: one convention, two names.

FANUC's W, P, R (pendant, LS files, RMI) are rotations about the fixed X, Y and Z axes of the
reference frame, applied in that order:

    R = Rz(r) Ry(p) Rx(w)

(fixed-axis XYZ, i.e. scipy's extrinsic `"xyz"`). URDF's `rpy="roll pitch yaw"` is the same
product, R = Rz(yaw) Ry(pitch) Rx(roll). Angles at this boundary are degrees for FANUC
(`*_deg`), radians for URDF (`*_rad`); translations are mm.

The angle extraction stays exact at pitch +-90 deg (gimbal lock), which the URDF's `tool0`
sits on (rpy = (pi, -pi/2, 0)): pitch from atan2 (no arcsin), yaw from the first column, and
roll from what is left after undoing yaw and pitch, so that an error of yaw near the lock
(where yaw and roll turn about almost the same axis) is absorbed by roll instead of showing
in the rebuilt matrix.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.transforms import pose, rot_x, rot_y, rot_z

F64 = NDArray[np.float64]

#: Below this cos(pitch) the yaw is set to 0 and roll carries the whole rotation about the axis.
_GIMBAL_COS = 1e-12


def matrix_from_rpy(rpy_rad: ArrayLike) -> F64:
    """R = Rz(yaw) Ry(pitch) Rx(roll) from (..., 3) angles (roll, pitch, yaw) [rad]."""
    a = np.asarray(rpy_rad, dtype=float)
    R: F64 = rot_z(a[..., 2]) @ rot_y(a[..., 1]) @ rot_x(a[..., 0])
    return R


def rpy_from_matrix(R: ArrayLike) -> F64:
    """Angles (roll, pitch, yaw) (..., 3) [rad] with R = Rz(yaw) Ry(pitch) Rx(roll); pitch in
    [-pi/2, pi/2], yaw and roll in (-pi, pi]."""
    R = np.asarray(R, dtype=float)
    cos_p = np.hypot(R[..., 0, 0], R[..., 1, 0])
    pitch = np.arctan2(-R[..., 2, 0], cos_p)
    yaw = np.where(cos_p > _GIMBAL_COS, np.arctan2(R[..., 1, 0], R[..., 0, 0]), 0.0)
    # what remains after Rz(yaw) Ry(pitch) is Rx(roll): read roll from its lower-right block
    M = np.swapaxes(rot_z(yaw) @ rot_y(pitch), -1, -2) @ R
    roll = np.arctan2(M[..., 2, 1], M[..., 2, 2])
    return np.stack([roll, pitch, yaw], axis=-1)


def pose_from_xyzwpr(xyzwpr: ArrayLike) -> F64:
    """Poses (N, 4, 4) [mm] from rows (N, 6) x_mm, y_mm, z_mm, w_deg, p_deg, r_deg."""
    v = np.atleast_2d(np.asarray(xyzwpr, dtype=float))
    return pose(matrix_from_rpy(np.radians(v[:, 3:6])), v[:, 0:3])


def xyzwpr_from_pose(T: ArrayLike) -> F64:
    """Rows (N, 6) x_mm, y_mm, z_mm, w_deg, p_deg, r_deg of poses (N, 4, 4) [mm]."""
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    return np.concatenate([T[:, :3, 3], np.degrees(rpy_from_matrix(T[:, :3, :3]))], axis=1)
