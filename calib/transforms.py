"""Rigid transforms: elementary rotations, rotation vectors (SO(3) exp/log and its right
Jacobian) and 4x4 homogeneous poses, batched over the leading axes.

`T_a_b` is the pose of frame b in frame a: it maps b coordinates to a coordinates.
Rotation vectors are used for the 6-DoF pieces of the model because Euler angles near 90 degree
pitch fake a singularity (REFERENCE.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]
_SMALL = 1e-8


def skew(v: ArrayLike) -> F64:
    """Cross-product matrix [v]x, shape (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rot_x(angle_rad: ArrayLike) -> F64:
    """Rotation about x, shape (...) -> (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 0, 0] = 1.0
    out[..., 1, 1], out[..., 1, 2], out[..., 2, 1], out[..., 2, 2] = c, -s, s, c
    return out


def rot_y(angle_rad: ArrayLike) -> F64:
    """Rotation about y, shape (...) -> (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 1, 1] = 1.0
    out[..., 0, 0], out[..., 0, 2], out[..., 2, 0], out[..., 2, 2] = c, s, -s, c
    return out


def rot_z(angle_rad: ArrayLike) -> F64:
    """Rotation about z, shape (...) -> (..., 3, 3)."""
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    out = np.zeros((*a.shape, 3, 3))
    out[..., 2, 2] = 1.0
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    return out


def rotvec_to_matrix(r_rad: ArrayLike) -> F64:
    """Rodrigues: rotation vector (..., 3) [rad] -> rotation matrix (..., 3, 3)."""
    r = np.asarray(r_rad, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = theta < _SMALL
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    return np.eye(3) + a * K + b * (K @ K)


def matrix_to_rotvec(R: ArrayLike) -> F64:
    """Inverse of `rotvec_to_matrix` for one rotation (3, 3) -> (3,), angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos_t))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * w
    if np.pi - theta < 1e-6:
        # near pi: axis from the symmetric part
        M = (R + np.eye(3)) / 2.0
        axis = M[:, int(np.argmax(np.diag(M)))]
        axis = axis / np.linalg.norm(axis)
        return theta * axis
    return theta / (2.0 * np.sin(theta)) * w


def so3_right_jacobian(r_rad: ArrayLike) -> F64:
    """Right Jacobian J_r of SO(3) at r (3,): exp(r + dr) = exp(r) exp(J_r(r) dr) to first order."""
    r = np.asarray(r_rad, dtype=float)
    theta = float(np.linalg.norm(r))
    K = skew(r)
    if theta < 1e-6:
        return np.eye(3) - 0.5 * K + (K @ K) / 6.0
    a = (1.0 - np.cos(theta)) / theta**2
    b = (theta - np.sin(theta)) / theta**3
    return np.eye(3) - a * K + b * (K @ K)


def pose(R: ArrayLike, t: ArrayLike) -> F64:
    """Homogeneous pose from rotation (..., 3, 3) and translation (..., 3)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*shape, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inverse(T: ArrayLike) -> F64:
    """Inverse of rigid poses (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return pose(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def apply(T: ArrayLike, p: ArrayLike) -> F64:
    """Map points p (..., 3) by poses T (..., 4, 4) (broadcast)."""
    T = np.asarray(T, dtype=float)
    p = np.asarray(p, dtype=float)
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def from_xyz_rpy(xyz: ArrayLike, rpy_rad: ArrayLike) -> F64:
    """URDF-style origin: translation, then fixed-axis roll-pitch-yaw R = Rz(y) Ry(p) Rx(r)."""
    r, p, y = np.asarray(rpy_rad, dtype=float)
    return pose(rot_z(y) @ rot_y(p) @ rot_x(r), xyz)


def to_euler_zyx(R: ArrayLike) -> F64:
    """Angles (rz, ry, rx) [rad] with R = Rz(rz) Ry(ry) Rx(rx); for display only."""
    R = np.asarray(R, dtype=float)
    ry = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    rz = float(np.arctan2(R[1, 0], R[0, 0]))
    rx = float(np.arctan2(R[2, 1], R[2, 2]))
    return np.array([rz, ry, rx])
