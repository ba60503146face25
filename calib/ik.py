"""Closed-form inverse kinematics of the nominal M-710iC/50, vectorised over flange poses.

Geometry (base frame B = FANUC World, controller angles): the wrist centre W lies d6 = 175 mm
behind the flange along its z axis. In the arm plane turned by J1, with r the signed horizontal
distance of W from the J1 axis and z its height,

    r = 150 + 870 sin J2 + L cos(J3 + delta),   z = 870 cos J2 + L sin(J3 + delta),

L = hypot(1016, 170), delta = atan2(170, 1016): a two-link problem with two elbow branches for
each of the two J1 branches (front and back). The wrist is spherical: with R_3_6 from the arm,
Rx(90) R_3_6 = Rz(theta4) Ry(-theta5) Rz(theta6), two branches (theta5 of either sign). Each
of J3, J4 and J6 also has its +-360 deg turn alternatives where the limits allow.

Singular poses (wrist centre on the J1 axis, theta5 = 0) and unreachable ones give no solution;
the output never holds NaN.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import robot
from calib.transforms import rot_x, rot_z

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_A1, _C2, _A3, _D4, _D6 = 150.0, 870.0, 170.0, 1016.0, 175.0
_L = float(np.hypot(_D4, _A3))
_DELTA = float(np.arctan2(_A3, _D4))
SINGULAR_TOL = 1e-9


@dataclass(frozen=True)
class IKSolutions:
    """All solutions of a batch: `q_deg` (M, 6) controller angles, `pose_index` (M,) the index
    of the flange pose each solves, `branch` (M,) an id of the branch (J1 front/back, elbow,
    wrist flip) and the whole-turn alternative."""

    q_deg: F64
    pose_index: I64
    branch: I64

    def for_pose(self, i: int) -> F64:
        """The solutions (K, 6) of pose i."""
        sel: F64 = self.q_deg[self.pose_index == i]
        return sel


def solve(
    T_base_flange: ArrayLike,
    limits: robot.JointLimits | None = None,
    *,
    turn_alternatives: bool = True,
) -> IKSolutions:
    """Every controller-angle solution within the limits for flange poses (N, 4, 4) [mm]."""
    T = np.asarray(T_base_flange, dtype=float).reshape(-1, 4, 4)
    limits = limits or robot.JointLimits()
    w = T[:, :3, 3] - _D6 * T[:, :3, 2]
    rho = np.hypot(w[:, 0], w[:, 1])
    turns = _turn_shifts(limits) if turn_alternatives else [np.zeros(6)]
    sols, idx, branches = [], [], []
    for back in (0, 1):
        j1 = np.arctan2(w[:, 1], w[:, 0]) + (np.pi if back else 0.0)
        u = (-rho if back else rho) - _A1
        v = w[:, 2]
        cos_e = (u**2 + v**2 - _C2**2 - _L**2) / (2.0 * _C2 * _L)
        arm_ok = (np.abs(cos_e) <= 1.0 + 1e-12) & (rho > SINGULAR_TOL)
        e0 = np.arccos(np.clip(cos_e, -1.0, 1.0))
        for elbow in (0, 1):
            e = e0 if elbow == 0 else -e0
            phi2 = np.arctan2(v, u) - np.arctan2(_L * np.sin(e), _C2 + _L * np.cos(e))
            j2 = np.pi / 2 - phi2
            j3 = phi2 + e - _DELTA
            for flip in (0, 1):
                wrist, ok = _wrist(T[:, :3, :3], j1, j2, j3, flip)
                q = np.column_stack([j1, j2, j3, wrist])
                q_deg = _wrap180(np.degrees(q))
                good = arm_ok & ok
                code = back * 4 + elbow * 2 + flip
                for k, shift in enumerate(turns):
                    qq = q_deg + shift
                    keep = good & limits.contains(qq)
                    sols.append(qq[keep])
                    idx.append(np.nonzero(keep)[0])
                    branches.append(np.full(int(keep.sum()), code * len(turns) + k))
    return IKSolutions(
        np.concatenate(sols).reshape(-1, 6),
        np.concatenate(idx).astype(np.int64),
        np.concatenate(branches).astype(np.int64),
    )


def _turn_shifts(limits: robot.JointLimits) -> list[F64]:
    """Every combination of whole turns (+-360 deg) that can bring a joint angle wrapped to
    [-180, 180) inside the limits (J3, J4, J6 of this robot have such alternatives)."""
    per_joint = []
    for lo, hi in zip(limits.lower_deg, limits.upper_deg, strict=True):
        ks = [k for k in (-1, 0, 1) if lo <= 180.0 + 360.0 * k and hi >= -180.0 + 360.0 * k]
        per_joint.append([360.0 * k for k in ks])
    return [np.array(c) for c in itertools.product(*per_joint)]


def _wrap180(a_deg: F64) -> F64:
    wrapped: F64 = (a_deg + 180.0) % 360.0 - 180.0
    return wrapped


def _wrist(
    R_base_flange: F64, j1: F64, j2: F64, j3: F64, flip: int
) -> tuple[F64, NDArray[np.bool_]]:
    """theta4..6 -> controller J4..J6 [rad] of one wrist branch, and where it is regular."""
    theta23 = (j2 - np.pi / 2) - (j2 + j3)
    R_b3 = rot_z(j1) @ rot_x(-np.pi / 2) @ rot_z(theta23)
    M = rot_x(np.pi / 2) @ np.swapaxes(R_b3, 1, 2) @ R_base_flange
    s5 = np.hypot(M[:, 0, 2], M[:, 1, 2])
    sign = 1.0 if flip == 0 else -1.0
    b = np.arctan2(sign * s5, M[:, 2, 2])  # = -theta5
    th4 = np.arctan2(sign * M[:, 1, 2], sign * M[:, 0, 2])
    th6 = np.arctan2(sign * M[:, 2, 1], -sign * M[:, 2, 0])
    ok = s5 > SINGULAR_TOL
    # theta4 = -J4, theta5 = -J5 = b, theta6 = -J6 (calib.robot)
    return np.column_stack([-th4, b, -th6]), ok
