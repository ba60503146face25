"""The identification Jacobian as calib.model computed it before the link-frame form (kept as
the oracle of tests/calib/test_model.py): every elementary operation's axis and origin in the
part frame from (N, 4, 4) frames, the base and sensor columns from skew matrices."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.model import _AXIS, _FS_R, BASE_NAMES, CHAIN, SENSOR_NAMES, SystemModel, cross
from calib.transforms import apply, inverse, skew, so3_right_jacobian

F64 = NDArray[np.float64]


def reference_point_and_jacobian(
    model: SystemModel, x: F64, q_deg: ArrayLike, c_sensor_mm: ArrayLike, active: Sequence[str]
) -> tuple[F64, F64]:
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    c_s = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (q.shape[0], 3))
    p = apply(model.fk(x, q), c_s)
    want = {name: j for j, name in enumerate(active)}
    J = np.zeros((q.shape[0], 3, len(active)))
    phi = model.joint_phi(x, q)
    c_phi, s_phi = np.cos(phi), np.sin(phi)
    pieces = model._pieces(x)
    T_pb = pieces.T_pb
    _base_columns(J, want, x, T_pb, p)
    A = np.broadcast_to(T_pb, (q.shape[0], 4, 4)).copy()
    P = np.eye(4)
    for (kind, name, joint), E in zip(CHAIN[1:-1], pieces.elems, strict=True):
        if kind == "rz":
            A = A @ P
            P = np.eye(4)
        col = want.get(name)
        if col is not None:
            axis_p = A[:, :3, :3] @ P[:3, _AXIS[kind]]
            if kind[0] == "r":
                origin = A[:, :3, :3] @ P[:3, 3] + A[:, :3, 3]
                J[:, :, col] = cross(axis_p, p - origin)
            else:
                J[:, :, col] = axis_p
        if kind == "rz":
            col0 = A[:, :, 0].copy()
            A[:, :, 0] = col0 * c_phi[:, joint, None] + A[:, :, 1] * s_phi[:, joint, None]
            A[:, :, 1] = A[:, :, 1] * c_phi[:, joint, None] - col0 * s_phi[:, joint, None]
        elif E is not None:
            P = P @ E
    A = A @ P
    _sensor_columns(model, J, want, x, A, c_s)
    return p, J


def _base_columns(J: F64, want: dict[str, int], x: F64, T_pb: F64, p: F64) -> None:
    R = T_pb[:3, :3]
    for k in range(3):
        if (col := want.get(BASE_NAMES[k])) is not None:
            J[:, k, col] = 1.0
    rot_cols = [want.get(n) for n in BASE_NAMES[3:]]
    if any(c is not None for c in rot_cols):
        p_b = apply(inverse(T_pb), p)
        D = -R @ skew(p_b) @ so3_right_jacobian(x[3:6])
        for k, col in enumerate(rot_cols):
            if col is not None:
                J[:, :, col] = D[:, :, k]


def _sensor_columns(
    model: SystemModel, J: F64, want: dict[str, int], x: F64, A: F64, c_s: F64
) -> None:
    R_a = A[:, :3, :3]
    for k in range(3):
        if (col := want.get(SENSOR_NAMES[k])) is not None:
            J[:, :, col] = R_a[:, :, k]
    rot_cols = [want.get(n) for n in SENSOR_NAMES[3:]]
    if any(c is not None for c in rot_cols):
        R_fs = model._pieces(x).T_fs[:3, :3]
        D = -(R_a @ R_fs) @ skew(c_s) @ so3_right_jacobian(x[_FS_R])
        for k, col in enumerate(rot_cols):
            if col is not None:
                J[:, :, col] = D[:, :, k]
