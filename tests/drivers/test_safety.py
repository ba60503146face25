"""Safety guard: joint limits and envelope checked before a motion leaves the process (property
tests with hypothesis)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import CartesianBox, Envelope, JointBox, JointLimits, MotionRefused, SafetyGuard
from drivers.errors import DeviceConfigError

LIMITS = JointLimits.m710ic50()
LO, HI = np.array(LIMITS.lower_deg), np.array(LIMITS.upper_deg)


def joints_within(lo: np.ndarray, hi: np.ndarray) -> st.SearchStrategy[np.ndarray]:
    cols = [st.floats(float(a), float(b), allow_nan=False) for a, b in zip(lo, hi, strict=True)]
    return st.tuples(*cols).map(lambda t: np.array(t))


@given(joints_within(LO, HI))
def test_every_target_inside_the_limits_is_accepted(q: np.ndarray) -> None:
    np.testing.assert_array_equal(SafetyGuard().check(q), q)


@given(
    joints_within(LO, HI),
    st.integers(0, 5),
    st.floats(1e-6, 1e4, allow_nan=False),
    st.booleans(),
)
def test_any_joint_beyond_its_limit_is_refused(
    q: np.ndarray, joint: int, excess: float, above: bool
) -> None:
    q = q.copy()
    q[joint] = HI[joint] + excess if above else LO[joint] - excess
    with pytest.raises(MotionRefused, match=f"J{joint + 1}="):
        SafetyGuard().check(q)


@given(joints_within(LO, HI), st.integers(0, 5), st.sampled_from([np.nan, np.inf, -np.inf]))
def test_non_finite_targets_are_refused(q: np.ndarray, joint: int, bad: float) -> None:
    q = q.copy()
    q[joint] = bad
    with pytest.raises(MotionRefused, match="finite"):
        SafetyGuard().check(q)


@pytest.mark.parametrize("value", [[0, 0, 0], np.zeros((2, 6)), "abc", None])
def test_wrong_shapes_are_refused(value: object) -> None:
    with pytest.raises(MotionRefused):
        SafetyGuard().check(value)  # type: ignore[arg-type]


KEEP_OUT = JointBox((-30, -90, -160, -360, -125, -360), (30, 135, 280, 360, 125, 360))
GUARD_OUT = SafetyGuard(envelope=Envelope(keep_out=(KEEP_OUT,)))


@settings(max_examples=60)
@given(st.floats(35, 180), st.floats(-180, -35))
def test_a_path_crossing_a_keep_out_box_is_refused_though_both_ends_are_outside(
    start_j1: float, end_j1: float
) -> None:
    start = np.array([start_j1, 0, 0, 0, -90, 0])
    end = np.array([end_j1, 0, 0, 0, -90, 0])
    GUARD_OUT.check(end)  # the target alone is fine
    with pytest.raises(MotionRefused, match="path enters keep-out"):
        GUARD_OUT.check(end, current_deg=start)


@given(joints_within(LO, HI), joints_within(LO, HI))
def test_keep_in_box_bounds_targets_and_paths(q: np.ndarray, cur: np.ndarray) -> None:
    box = JointBox((-90, -45, -60, -180, -120, -180), (90, 90, 120, 180, 120, 180))
    guard = SafetyGuard(envelope=Envelope(keep_in=box))
    inside = bool(box.contains(q[None])[0] and box.contains(cur[None])[0])
    if inside:  # a box is convex: the straight joint path stays inside
        np.testing.assert_array_equal(guard.check(q, current_deg=cur), q)
    elif not box.contains(q[None])[0]:
        with pytest.raises(MotionRefused):
            guard.check(q, current_deg=cur)


@given(joints_within(LO, HI), st.floats(0.5, 30))
def test_max_step_limits_the_move(q: np.ndarray, step: float) -> None:
    guard = SafetyGuard(envelope=Envelope(max_step_deg=(step,) * 6))
    cur = np.clip(q + 2 * step, LO, HI)
    if np.any(np.abs(q - cur) > step):
        with pytest.raises(MotionRefused, match="max step"):
            guard.check(q, current_deg=cur)


def test_cartesian_envelope_uses_the_injected_points_function() -> None:
    def flange_mm(q: np.ndarray) -> np.ndarray:  # a stand-in "kinematics": x follows J1
        return np.stack([q[:, 0] * 10.0, np.zeros(len(q)), np.full(len(q), 500.0)], axis=-1)

    env = Envelope(cartesian=CartesianBox((-1000, -1000, 0), (1000, 1000, 2000)))
    guard = SafetyGuard(envelope=env, points_mm=flange_mm)
    guard.check([90, 0, 0, 0, 0, 0], current_deg=[0, 0, 0, 0, 0, 0])
    with pytest.raises(MotionRefused, match="Cartesian"):
        guard.check([120, 0, 0, 0, 0, 0], current_deg=[0, 0, 0, 0, 0, 0])
    with pytest.raises(DeviceConfigError):
        SafetyGuard(envelope=env)


def test_bad_limits_are_a_configuration_error() -> None:
    with pytest.raises(DeviceConfigError):
        JointLimits((0,) * 6, (-1,) * 6)
    with pytest.raises(DeviceConfigError):
        JointLimits((0,) * 5, (1,) * 5)


def test_duration_is_the_slowest_joint() -> None:
    guard = SafetyGuard()
    t = guard.duration_s([0] * 6, [175, 0, 0, 0, 0, 355], speed_pct=50)
    assert t == pytest.approx(2.0)


def test_a_move_with_acceleration_is_a_trapezoid_or_a_triangle_plus_its_settling() -> None:
    """`move_time_s`: at its speed after accel_s (|dq| / v + accel_s), a move too short to
    reach it a triangle (2 sqrt(|dq| accel_s / v)), the slowest joint's, then the settling."""
    limits = JointLimits.m710ic50()
    home = np.zeros(6)
    long_move = np.array([90.0, 0, 0, 0, 0, 0])  # J1 at 175 deg/s x 0.5: 87.5 deg/s
    assert limits.move_time_s(home, long_move, 0.5) == pytest.approx(90 / 87.5)
    assert limits.move_time_s(home, long_move, 0.5, 0.3, 0.15) == pytest.approx(
        90 / 87.5 + 0.3 + 0.15
    )
    short = np.array([5.0, 0, 0, 0, 0, 1.0])  # 5 deg < 87.5 x 0.3: J1 never at speed
    want = 2.0 * np.sqrt(5.0 * 0.3 / 87.5)
    assert limits.move_time_s(home, short, 0.5, 0.3) == pytest.approx(want)
    assert want < 5.0 / 87.5 + 0.3  # never longer than the trapezoid's formula
    assert limits.move_time_s(home, home, 0.5, 0.3, 0.15) == 0.0


def test_the_drivers_fallback_limits_are_the_data_sheets() -> None:
    """The data sheet's home is calib/robot.py and the app's guard reads it through the cell
    file (app.line.station.cell_guard); drivers/ may not import calib/, so the fallback of a
    robot driver opened without a guard (tests, fakes) repeats it, pinned here."""
    from calib import robot

    assert np.array_equal(LIMITS.lower_deg, robot.JointLimits().lower_deg)
    assert np.array_equal(LIMITS.upper_deg, robot.JointLimits().upper_deg)
    assert np.array_equal(LIMITS.speed_deg_s, robot.JOINT_SPEED_DEG_S)


def test_max_speed_is_part_of_the_guard() -> None:
    guard = SafetyGuard(max_speed_pct=10.0)
    assert guard.check_speed(10) == 10.0
    with pytest.raises(MotionRefused, match="above the guard's 10 %"):
        guard.check_speed(10.5)
    with pytest.raises(DeviceConfigError):
        guard.check_speed(0)
    for bad in (0.0, 120.0, float("nan")):
        with pytest.raises(DeviceConfigError):
            SafetyGuard(max_speed_pct=bad)
