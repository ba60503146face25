"""The motion safety guard: every joint motion is checked here before it leaves the process.

The guard knows no kinematics (drivers never do). It checks, in controller (pendant) angles J1..J6
in degrees:

- the command is six finite numbers inside the joint limits;
- the target and the straight joint-space path to it stay inside the configured envelope: a
  keep-in joint box, no keep-out joint box, and (optionally) a Cartesian box for points that the
  caller's ``points_mm`` function computes from the joints (the app injects the nominal forward
  kinematics of the flange and sensor; the guard only compares numbers);
- the move is not larger than ``max_step_deg`` per joint, if configured;
- the programmed speed is not above ``max_speed_pct`` (100 by default; the contract tests on a
  real robot and commissioning moves run at 10).

Limits and envelope are frozen dataclasses resolved from the cell configuration; a refusal raises
MotionRefused and nothing is sent. This is a process-level check: the robot's own DCS and the
safety PLC stay the safety functions of the cell.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.errors import DeviceConfigError, MotionRefused

FloatArray = NDArray[np.float64]
N_JOINTS = 6
_PATH_STEP_DEG = 1.0  # joint-space sampling of the path for keep-out and Cartesian checks


def _six(values: Sequence[float], what: str) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if len(out) != N_JOINTS or not all(np.isfinite(out)):
        raise DeviceConfigError(f"{what} needs {N_JOINTS} finite values, got {values!r}")
    return out


@dataclass(frozen=True)
class JointBox:
    """An axis-aligned box in controller joint space, degrees (inclusive bounds)."""

    lower_deg: tuple[float, ...]
    upper_deg: tuple[float, ...]

    def __post_init__(self) -> None:
        lo, hi = _six(self.lower_deg, "lower_deg"), _six(self.upper_deg, "upper_deg")
        if any(a > b for a, b in zip(lo, hi, strict=True)):
            raise DeviceConfigError(f"joint box lower {lo} exceeds upper {hi}")
        object.__setattr__(self, "lower_deg", lo)
        object.__setattr__(self, "upper_deg", hi)

    def contains(self, q_deg: FloatArray) -> NDArray[np.bool_]:
        """Which rows of ``q_deg`` (shape (n, 6)) lie in the box."""
        return np.all((q_deg >= self.lower_deg) & (q_deg <= self.upper_deg), axis=-1)


@dataclass(frozen=True)
class JointLimits(JointBox):
    """Mechanical joint limits [deg] and maximum joint speeds [deg/s]."""

    speed_deg_s: tuple[float, ...] = (175.0, 175.0, 175.0, 250.0, 250.0, 355.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        speed = _six(self.speed_deg_s, "speed_deg_s")
        if min(speed) <= 0:
            raise DeviceConfigError(f"joint speeds must be > 0, got {speed}")
        object.__setattr__(self, "speed_deg_s", speed)

    def move_time_s(
        self,
        start_deg: ArrayLike,
        end_deg: ArrayLike,
        speed_frac: float,
        accel_s: float = 0.0,
        settle_s: float = 0.0,
    ) -> float:
        """Time [s] of a synchronised joint move at `speed_frac` of the joint speeds (programmed
        speed x override), the slowest joint's: |dq| / v at constant speed (accel_s 0); with
        each joint reaching its speed in accel_s (a trapezoid: |dq| / v + accel_s, a triangle
        2 sqrt(|dq| accel_s / v) for a move too short to reach it), plus settle_s at its end (a
        FINE stop). 0 for no motion."""
        delta = np.abs(np.asarray(end_deg, float) - np.asarray(start_deg, float))
        if not np.any(delta > 0):
            return 0.0
        v = np.asarray(self.speed_deg_s) * speed_frac
        at_speed = delta / v
        if accel_s > 0:
            at_speed = np.where(
                delta >= v * accel_s, at_speed + accel_s, 2.0 * np.sqrt(delta * accel_s / v)
            )
        return float(np.max(at_speed)) + settle_s

    @classmethod
    def m710ic50(cls) -> JointLimits:
        """FANUC M-710iC/50 controller-angle limits and speeds (REFERENCE.md): the fallback of
        a robot opened without a guard. The data sheet's home is calib/robot.py, which the
        application's guard reads through the cell file; a test pins this copy to it."""
        return cls(
            lower_deg=(-180.0, -90.0, -160.0, -360.0, -125.0, -360.0),
            upper_deg=(180.0, 135.0, 280.0, 360.0, 125.0, 360.0),
        )


@dataclass(frozen=True)
class CartesianBox:
    """An axis-aligned keep-in box in the robot base frame, millimetres."""

    lower_mm: tuple[float, float, float]
    upper_mm: tuple[float, float, float]


@dataclass(frozen=True)
class Envelope:
    """Where motion is allowed, on top of the joint limits. Empty means: limits only."""

    keep_in: JointBox | None = None
    keep_out: tuple[JointBox, ...] = ()
    max_step_deg: tuple[float, ...] | None = None
    cartesian: CartesianBox | None = None


PointsFn = Callable[[FloatArray], FloatArray]
"""Maps joints (n, 6) [deg] to guarded points (n, k, 3) [mm] in the base frame."""


@dataclass(frozen=True)
class SafetyGuard:
    """Checks motion commands against joint limits and an envelope (see module docstring)."""

    limits: JointLimits = field(default_factory=JointLimits.m710ic50)
    envelope: Envelope = field(default_factory=Envelope)
    points_mm: PointsFn | None = None
    max_speed_pct: float = 100.0

    def __post_init__(self) -> None:
        if self.envelope.cartesian is not None and self.points_mm is None:
            raise DeviceConfigError("a Cartesian envelope needs a points_mm function")
        if not 0 < self.max_speed_pct <= 100:
            raise DeviceConfigError(f"max_speed_pct must be in (0, 100], got {self.max_speed_pct}")

    def check_speed(self, speed_pct: float) -> float:
        """The programmed speed [%] if it is within (0, max_speed_pct]; MotionRefused above
        the guard's maximum, DeviceConfigError outside (0, 100]."""
        if not 0 < speed_pct <= 100:
            raise DeviceConfigError(f"speed_pct must be in (0, 100], got {speed_pct!r}")
        if speed_pct > self.max_speed_pct:
            raise MotionRefused(f"speed {speed_pct:g} % above the guard's {self.max_speed_pct:g} %")
        return float(speed_pct)

    def check(self, q_deg: ArrayLike, current_deg: ArrayLike | None = None) -> FloatArray:
        """Return the validated target as float64 (6,), or raise MotionRefused."""
        q = self._as_joints(q_deg, "target")
        self._check_point(q)
        if current_deg is None:
            return q
        cur = self._as_joints(current_deg, "current position")
        step = self.envelope.max_step_deg
        if step is not None and np.any(np.abs(q - cur) > np.asarray(step)):
            raise MotionRefused(f"move {np.round(q - cur, 3)} exceeds max step {step} deg")
        self._check_path(cur, q)
        return q

    def duration_s(self, start_deg: ArrayLike, end_deg: ArrayLike, speed_pct: float) -> float:
        """Time of a synchronised joint move at ``speed_pct`` percent of the joint speeds."""
        return self.limits.move_time_s(start_deg, end_deg, speed_pct / 100.0)

    # -- internals ----------------------------------------------------------------------------
    @staticmethod
    def _as_joints(q_deg: ArrayLike, what: str) -> FloatArray:
        try:
            q = np.asarray(q_deg, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise MotionRefused(f"{what}: not a joint vector: {q_deg!r}") from exc
        if q.shape != (N_JOINTS,):
            raise MotionRefused(f"{what}: expected {N_JOINTS} joint angles, got shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise MotionRefused(f"{what}: joint angles must be finite, got {q}")
        return q

    def _check_point(self, q: FloatArray) -> None:
        rows = q[None, :]
        if not self.limits.contains(rows)[0]:
            bad = [
                f"J{i + 1}={v:.3f}"
                for i, (v, lo, hi) in enumerate(
                    zip(q, self.limits.lower_deg, self.limits.upper_deg, strict=True)
                )
                if not lo <= v <= hi
            ]
            raise MotionRefused(f"outside the joint limits: {', '.join(bad)}")
        self._check_envelope(rows, "target")

    def _check_path(self, start: FloatArray, end: FloatArray) -> None:
        n = max(2, int(np.ceil(np.max(np.abs(end - start)) / _PATH_STEP_DEG)) + 1)
        path = start + np.linspace(0.0, 1.0, n)[:, None] * (end - start)
        self._check_envelope(path, "path")

    def _check_envelope(self, rows: FloatArray, what: str) -> None:
        env = self.envelope
        if env.keep_in is not None and not np.all(env.keep_in.contains(rows)):
            raise MotionRefused(f"{what} leaves the keep-in joint box")
        for i, box in enumerate(env.keep_out):
            if np.any(box.contains(rows)):
                raise MotionRefused(f"{what} enters keep-out joint box #{i}")
        if env.cartesian is not None and self.points_mm is not None:
            pts = np.asarray(self.points_mm(rows), dtype=np.float64).reshape(len(rows), -1, 3)
            lo, hi = np.asarray(env.cartesian.lower_mm), np.asarray(env.cartesian.upper_mm)
            if not np.all((pts >= lo) & (pts <= hi)):
                raise MotionRefused(f"{what} leaves the Cartesian envelope")
