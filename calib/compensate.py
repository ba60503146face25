"""Compensated robot targets: what to send a controller that uses its nominal model so that
the real (identified) robot reaches the intended sensor poses.

The controller knows only the nominal M-710iC/50 with the nominal user frame (part) and tool
frame (sensor). For an intended sensor pose T in the part frame (RoboDK's "filter target"
practice, REFERENCE.md):

1. inverse kinematics on the identified model x: the joints q* at which the real robot puts the
   sensor at T (`ik_refine.solve_on_model`, every branch; the one nearest the original joints);
2. forward kinematics on the nominal model: T_cmd = FK_nominal(q*), the Cartesian target that
   makes a nominal controller go to q* (for programs taught in Cartesian positions);
3. inverse kinematics on the nominal model of T_cmd (the controller's own computation), the
   branch nearest q*: the compensated joints. They equal q* to ~1e-9 deg; the round trip checks
   that the controller lands on q* and not on another branch.

The original joints are what the nominal controller would use for T: given (joint targets, whose
nominal pose is by definition the intended pose), or the nominal inverse kinematics of T, the
branch nearest a reference (the row's own hint, else the previous row's result, else
`start_q_deg`: a program moves from one point to the next). A row that cannot be compensated
is flagged with its reason; nothing is raised for it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import ik, ik_refine, robot
from calib.model import SystemModel
from calib.transforms import inverse

F64 = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_NO_LIMITS = robot.JointLimits(np.full(6, -1e9), np.full(6, 1e9))


@dataclass(frozen=True)
class CompensationSettings:
    """max_joint_change_deg: largest change of any joint between the original and the
    compensated joints (a larger one means another branch, or a pose at a singularity; RoboDK
    keeps the branch within about 20 deg); roundtrip_tol_deg: how close the nominal inverse
    kinematics of the Cartesian command must return the joints; start_q_deg: the reference of
    the first pose target without a hint of its own."""

    max_joint_change_deg: float = 20.0
    roundtrip_tol_deg: float = 1e-6
    start_q_deg: tuple[float, ...] = tuple(robot.HOME_DEG.tolist())

    #: max_joint_change_deg is in (0, this]
    MAX_JOINT_CHANGE_DEG: ClassVar[float] = 180.0

    def __post_init__(self) -> None:
        if not 0.0 < self.max_joint_change_deg <= self.MAX_JOINT_CHANGE_DEG:
            raise ValueError("max_joint_change_deg must be in (0, 180]")
        if not 0.0 < self.roundtrip_tol_deg <= 1e-2:
            raise ValueError("roundtrip_tol_deg must be in (0, 0.01]")
        if len(self.start_q_deg) != 6:
            raise ValueError("start_q_deg needs 6 controller angles [deg]")


@dataclass(frozen=True)
class Compensation:
    """Per target (N rows): `T_intended` (N, 4, 4) the intended sensor pose (part frame, mm),
    `q_nominal_deg` (N, 6) the original joints (what the nominal controller uses for it),
    `q_deg` (N, 6) the compensated joints, `T_command` (N, 4, 4) the compensated Cartesian
    target for a nominal controller, `ok` (N,) and `reason` (N,) ('' where ok). Rows not ok
    hold NaN where nothing could be computed."""

    T_intended: F64
    q_nominal_deg: F64
    q_deg: F64
    T_command: F64
    ok: BoolArray
    reason: tuple[str, ...]

    @property
    def joint_change_deg(self) -> F64:
        """Largest joint change per row [deg] (compensated - original)."""
        out: F64 = np.max(np.abs(self.q_deg - self.q_nominal_deg), axis=1)
        return out


def nominal_base_flange(model: SystemModel, T_part_sensor: ArrayLike) -> F64:
    """Flange poses in the base frame (N, 4, 4) of sensor poses, on the nominal model."""
    x0 = model.nominal_x()
    T = np.asarray(T_part_sensor, dtype=float).reshape(-1, 4, 4)
    out: F64 = inverse(model.T_part_base(x0)) @ T @ inverse(model.T_flange_sensor(x0))
    return out


def nominal_ik(
    model: SystemModel,
    T_part_sensor: ArrayLike,
    q_hint_deg: ArrayLike | None = None,
    settings: CompensationSettings | None = None,
) -> tuple[F64, list[str]]:
    """The nominal controller's joints (N, 6) for sensor poses (N, 4, 4): the branch nearest
    each row's hint (N, 6) (NaN rows: none), else the previous row's result, else
    settings.start_q_deg. Rows without a solution are NaN, with their reason."""
    settings = settings or CompensationSettings()
    T_bf = nominal_base_flange(model, T_part_sensor)
    n = T_bf.shape[0]
    sols = ik.solve(T_bf, model.limits)
    hints = np.full((n, 6), np.nan) if q_hint_deg is None else np.asarray(q_hint_deg, float)
    q = np.full((n, 6), np.nan)
    reasons = [""] * n
    bounds = np.searchsorted(sols.pose_index, np.arange(n + 1))
    previous = np.asarray(settings.start_q_deg, dtype=float)
    for i in range(n):
        options = sols.q_deg[bounds[i] : bounds[i + 1]]
        if options.shape[0] == 0:
            reasons[i] = _why_no_solution(T_bf[i])
            continue
        ref = hints[i] if np.all(np.isfinite(hints[i])) else previous
        q[i] = options[np.argmin(np.linalg.norm(options - ref, axis=1))]
        previous = q[i]
    return q, reasons


def _why_no_solution(T_base_flange: F64) -> str:
    if ik.solve(T_base_flange, _NO_LIMITS, turn_alternatives=False).q_deg.shape[0] == 0:
        return "out of reach of the robot (or at a singularity): no inverse kinematics solution"
    return "no inverse kinematics solution within the joint limits"


def _nearest(
    q_deg: F64, pose_index: NDArray[np.int64], keep: BoolArray, ref_deg: F64
) -> tuple[F64, F64]:
    """Per row of ref_deg (N, 6): the kept solution nearest it (NaN if none) and its largest
    joint change [deg] (inf if none)."""
    n = ref_deg.shape[0]
    q, idx = q_deg[keep], pose_index[keep]
    dist = np.linalg.norm(q - ref_deg[idx], axis=1)
    order = np.lexsort((dist, idx))  # by pose, nearest first
    first = order[np.r_[True, idx[order][1:] != idx[order][:-1]]] if order.size else order
    best = np.full((n, 6), np.nan)
    best[idx[first]] = q[first]
    change = np.max(np.abs(best - ref_deg), axis=1)
    return best, np.where(np.isnan(change), np.inf, change)


def compensate_poses(
    model: SystemModel,
    x: F64,
    T_intended: ArrayLike,
    q_hint_deg: ArrayLike | None = None,
    settings: CompensationSettings | None = None,
) -> Compensation:
    """Compensate intended sensor poses (N, 4, 4) in the part frame [mm]; q_hint_deg (N, 6):
    optional joints whose branch each row keeps (NaN rows: none)."""
    settings = settings or CompensationSettings()
    T = np.asarray(T_intended, dtype=float).reshape(-1, 4, 4)
    q_nom, reasons = nominal_ik(model, T, q_hint_deg, settings)
    return _compensate(model, x, T, q_nom, reasons, settings)


def compensate_joints(
    model: SystemModel,
    x: F64,
    q_nominal_deg: ArrayLike,
    settings: CompensationSettings | None = None,
) -> Compensation:
    """Compensate joint targets (N, 6) [deg]: the intended pose of a row is where the nominal
    model says its joints put the sensor."""
    settings = settings or CompensationSettings()
    q_nom = np.array(q_nominal_deg, dtype=float).reshape(-1, 6)
    T = model.fk(model.nominal_x(), q_nom)
    return _compensate(model, x, T, q_nom, [""] * q_nom.shape[0], settings)


def _compensate(
    model: SystemModel,
    x: F64,
    T: F64,
    q_nom: F64,
    reasons: list[str],
    settings: CompensationSettings,
) -> Compensation:
    q_id = _identified_joints(model, x, T, q_nom, reasons, settings)
    q, T_cmd = _controller_joints(model, q_id, reasons, settings)
    ok = np.array([not r for r in reasons], dtype=bool)
    return Compensation(T, q_nom, q, T_cmd, ok, tuple(reasons))


def _identified_joints(
    model: SystemModel,
    x: F64,
    T: F64,
    q_nom: F64,
    reasons: list[str],
    settings: CompensationSettings,
) -> F64:
    """Step 1: the identified robot's joints for the intended poses, nearest the original
    joints; rows without one within max_joint_change_deg get their reason."""
    ok = np.array([not r for r in reasons], dtype=bool)
    sols = ik_refine.solve_on_model(model, x, T, model.limits)
    q_id, change = _nearest(sols.q_deg, sols.pose_index, sols.converged, np.nan_to_num(q_nom))
    for i in np.flatnonzero(ok & ~np.isfinite(change)):
        reasons[i] = "no inverse kinematics solution on the identified model within the limits"
    for i in np.flatnonzero(ok & np.isfinite(change) & (change > settings.max_joint_change_deg)):
        reasons[i] = (
            f"the identified model's nearest solution is {change[i]:.1f} deg from the original "
            f"joints (more than {settings.max_joint_change_deg:g} deg: another branch or a "
            "singularity)"
        )
    return q_id


def _controller_joints(
    model: SystemModel, q_id: F64, reasons: list[str], settings: CompensationSettings
) -> tuple[F64, F64]:
    """Steps 2 and 3: the Cartesian command T_cmd = FK_nominal(q_id) and the nominal inverse
    kinematics of it nearest q_id (the controller's own computation): (joints, T_cmd)."""
    ok = np.array([not r for r in reasons], dtype=bool)
    n = q_id.shape[0]
    T_cmd = np.full((n, 4, 4), np.nan)
    q = np.full((n, 6), np.nan)
    if not np.any(ok):
        return q, T_cmd
    T_cmd[ok] = model.fk(model.nominal_x(), q_id[ok])
    back = ik.solve(nominal_base_flange(model, T_cmd[ok]), model.limits)
    keep = np.ones(back.q_deg.shape[0], dtype=bool)
    q[ok], gap = _nearest(back.q_deg, back.pose_index, keep, q_id[ok])
    for k, i in enumerate(np.flatnonzero(ok)):
        if not gap[k] <= settings.roundtrip_tol_deg:
            reasons[i] = (
                "the nominal inverse kinematics of the compensated pose does not return the "
                f"compensated joints (gap {gap[k]:.2g} deg): a singular pose"
            )
    return q, T_cmd
