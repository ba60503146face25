"""Inverse kinematics on the identified model: the nominal closed form, refined by a few damped
Gauss-Newton (Levenberg-Marquardt) steps on the controller angles.

Why: `calib.ik` solves the nominal M-710iC/50. The real, calibrated robot differs from it by
the identified parameters x (joint zero offsets of a few mrad, link lengths and twists off by
tenths of a millimetre, the part->base and flange->sensor transforms): with a 2 m lever, the
nominal solution puts the sensor millimetres away from where the plan wants it, so the sphere
would not appear where it was planned in the 27 x 37 x 10 mm field of view. Starting from the
closed form (every branch), a few steps on `SystemModel.fk(x, q)` reach the planned sensor pose
to well below a micrometre.

Residual per configuration (6): position error [mm] and the rotation vector of R R_target^T
[rad] times `ROT_WEIGHT_MM` (1 rad ~ 1000 mm, so 1 mrad weighs like 1 mm at the flange). The
Jacobian is analytic (geometric Jacobian of the model's modified-DH chain, through the J2/J3
coupling of the controller angles); everything is batched over configurations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import ik, robot
from calib.model import INDEX, SystemModel
from calib.transforms import inverse

F64 = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Weight of the rotation residual [mm per rad].
ROT_WEIGHT_MM = 1000.0
#: Convergence: position [mm] and rotation [rad] errors below these.
TOL_MM = 1e-7
TOL_RAD = 1e-10
#: Largest change of one joint per iteration [rad].
MAX_STEP_RAD = 0.1


@dataclass(frozen=True)
class Refined:
    """Refined configurations: `q_deg` (K, 6) controller angles, the remaining position
    error [mm] and rotation error [rad] (K,), `converged` (K,) (reached the tolerances within
    the joint limits) and the iterations taken."""

    q_deg: F64
    position_error_mm: F64
    rotation_error_rad: F64
    converged: BoolArray
    iterations: int


@dataclass(frozen=True)
class RefinedSolutions(ik.IKSolutions):
    """`ik.IKSolutions` on the identified model, with each solution's remaining errors and
    whether it converged (non-converged ones are kept, flagged)."""

    position_error_mm: F64
    rotation_error_rad: F64
    converged: BoolArray


def sensor_target(p_part_mm: ArrayLike, c_sensor_mm: ArrayLike, R_part_sensor: ArrayLike) -> F64:
    """T_part_sensor (K, 4, 4) that puts the sphere centre p_part_mm (K, 3) at c_sensor_mm
    (K, 3) in the sensor frame with the sensor orientation R_part_sensor (K, 3, 3)."""
    R = np.asarray(R_part_sensor, dtype=float).reshape(-1, 3, 3)
    k = R.shape[0]
    p = np.broadcast_to(np.asarray(p_part_mm, dtype=float), (k, 3))
    c = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (k, 3))
    T = np.zeros((k, 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p - np.einsum("kij,kj->ki", R, c)
    T[:, 3, 3] = 1.0
    return T


def refine(
    model: SystemModel,
    x: F64,
    T_part_sensor_target: ArrayLike,
    q0_deg: ArrayLike,
    *,
    limits: robot.JointLimits | None = None,
    max_iter: int = 5,
    damping: float = 1e-9,
) -> Refined:
    """Damped Gauss-Newton on the controller angles from q0_deg (K, 6) so that
    model.fk(x, q) reaches T_part_sensor_target (K, 4, 4) (or one pose for all)."""
    q = np.array(q0_deg, dtype=float).reshape(-1, 6)
    k = q.shape[0]
    target = np.broadcast_to(np.asarray(T_part_sensor_target, dtype=float), (k, 4, 4))
    limits = limits or model.limits
    consts = model._constants(x)
    dtheta = x[[INDEX[f"dtheta{i}"] for i in range(1, 7)]]
    # dphi / dq [per rad of controller angle]: the J2/J3 coupling
    coupling = robot.COUPLING
    active = np.ones(k, dtype=bool)
    pos_err = np.zeros(k)
    rot_err = np.zeros(k)
    iterations = 0
    for it in range(max_iter + 1):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        phi = np.radians(q[idx]) @ coupling.T + robot.THETA_OFFSET_RAD + dtheta
        T, z, o = _chain(consts, phi)
        r, pe, re = _residual(T, target[idx])
        pos_err[idx], rot_err[idx] = pe, re
        done = (pe < TOL_MM) & (re < TOL_RAD)
        active[idx[done]] = False
        if it == max_iter or np.all(done):
            break
        iterations = it + 1
        sel = ~done
        idx, r, T, z, o = idx[sel], r[sel], T[sel], z[sel], o[sel]
        J = _jacobian(T, z, o) @ coupling  # (m, 6, 6) per rad of controller angle
        JT = np.swapaxes(J, 1, 2)
        A = JT @ J
        A += damping * np.eye(6) * (1.0 + np.trace(A, axis1=1, axis2=2))[:, None, None]
        dq = np.linalg.solve(A, -(JT @ r[..., None]))[..., 0]
        # trust region: at most MAX_STEP_RAD per joint (no jumps to another branch)
        big = np.abs(dq).max(axis=1)
        dq *= np.minimum(1.0, MAX_STEP_RAD / np.maximum(big, 1e-300))[:, None]
        q[idx] += np.degrees(dq)
    converged = (pos_err < TOL_MM) & (rot_err < TOL_RAD) & limits.contains(q)
    return Refined(q, pos_err, rot_err, converged, iterations)


def solve_on_model(
    model: SystemModel,
    x: F64,
    T_part_sensor_target: ArrayLike,
    limits: robot.JointLimits | None = None,
    *,
    turn_alternatives: bool = True,
    max_iter: int = 5,
) -> RefinedSolutions:
    """Every branch reaching the sensor poses T_part_sensor_target (N, 4, 4) on the
    identified model x: flange poses through the model's T_part_base(x) and
    T_flange_sensor(x), the nominal closed form (`ik.solve`), each solution refined."""
    T = np.asarray(T_part_sensor_target, dtype=float).reshape(-1, 4, 4)
    limits = limits or model.limits
    T_base_flange = inverse(model.T_part_base(x)) @ T @ inverse(model.T_flange_sensor(x))
    # a wider window for the closed form: refinement moves the angles by a little
    widened = robot.JointLimits(limits.lower_deg - 1.0, limits.upper_deg + 1.0)
    sols = ik.solve(T_base_flange, widened, turn_alternatives=turn_alternatives)
    # whole-turn alternatives of one branch share the refinement step (FK is 360-periodic in
    # every controller angle): refine one per (pose, branch code), shift the others alike
    n_turns = len(ik.turn_shifts(widened)) if turn_alternatives else 1
    group = sols.pose_index * ik.N_BRANCHES + sols.branch // n_turns
    _, first, inv = np.unique(group, return_index=True, return_inverse=True)
    # a representative inside [-180, 180] keeps the damped steps away from the limit test
    q_first = sols.q_deg[first]
    ref = refine(model, x, T[sols.pose_index[first]], q_first, limits=_NO_LIMITS,
                 max_iter=max_iter)  # fmt: skip
    q_deg = sols.q_deg + (ref.q_deg - q_first)[inv]
    converged = ref.converged[inv] & limits.contains(q_deg)
    return RefinedSolutions(
        q_deg,
        sols.pose_index,
        sols.branch,
        ref.position_error_mm[inv],
        ref.rotation_error_rad[inv],
        converged,
    )


_NO_LIMITS = robot.JointLimits(np.full(6, -1e9), np.full(6, 1e9))


def _chain(consts: list[F64], phi: F64) -> tuple[F64, F64, F64]:
    """T (m, 4, 4) and each joint's rotation axis z (m, 6, 3) and origin o (m, 6, 3), all in
    the part frame, for joint rotation angles phi (m, 6) [rad]."""
    m = phi.shape[0]
    c, s = np.cos(phi), np.sin(phi)
    M = np.broadcast_to(consts[0], (m, 4, 4)).copy()
    z = np.empty((m, 6, 3))
    o = np.empty((m, 6, 3))
    for i in range(6):
        z[:, i] = M[:, :3, 2]
        o[:, i] = M[:, :3, 3]
        col0 = M[:, :, 0].copy()
        M[:, :, 0] = col0 * c[:, i, None] + M[:, :, 1] * s[:, i, None]
        M[:, :, 1] = M[:, :, 1] * c[:, i, None] - col0 * s[:, i, None]
        M = M @ consts[i + 1]
    return M, z, o


def _residual(T: F64, target: F64) -> tuple[F64, F64, F64]:
    """Weighted residual (m, 6) and the position [mm] and rotation [rad] error norms."""
    dp = T[:, :3, 3] - target[:, :3, 3]
    dR = T[:, :3, :3] @ np.swapaxes(target[:, :3, :3], 1, 2)  # spatial rotation error
    w = 0.5 * np.stack(
        [dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]], axis=1
    )
    sin_t = np.linalg.norm(w, axis=1)
    cos_t = 0.5 * (np.trace(dR, axis1=1, axis2=2) - 1.0)
    theta = np.arctan2(sin_t, cos_t)
    scale = np.where(sin_t > 1e-12, theta / np.where(sin_t > 1e-12, sin_t, 1.0), 1.0)
    rv = w * scale[:, None]
    r = np.concatenate([dp, ROT_WEIGHT_MM * rv], axis=1)
    return r, np.linalg.norm(dp, axis=1), theta


def _jacobian(T: F64, z: F64, o: F64) -> F64:
    """Weighted geometric Jacobian (m, 6, 6) of the residual w.r.t. the joint angles phi."""
    p = T[:, None, :3, 3]
    J = np.empty((T.shape[0], 6, 6))
    J[:, :3, :] = np.swapaxes(np.cross(z, p - o), 1, 2)
    J[:, 3:, :] = ROT_WEIGHT_MM * np.swapaxes(z, 1, 2)
    return J
