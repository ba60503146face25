"""Compensated targets: the identified robot reaches the intended pose at the compensated
joints, a nominal controller lands on them, and rows that cannot be compensated say why."""

from __future__ import annotations

import numpy as np

from calib import ik, robot
from calib.compensate import (
    CompensationSettings,
    compensate_joints,
    compensate_poses,
    nominal_base_flange,
    nominal_ik,
)
from calib.model import INDEX, PAPER_30, SystemModel, unit_of
from calib.transforms import pose, rotvec_to_matrix

MODEL = SystemModel(
    pose(rotvec_to_matrix([0.01, -0.02, 0.3]), [2000.0, -300.0, 100.0]),
    pose(rotvec_to_matrix([0.0, 0.0, 0.5]), [10.0, 20.0, 150.0]),
)


def perturbed_x(seed: int) -> np.ndarray:
    """The identified robot: each of the 30 parameters off by ~0.5 mm / 1 mrad."""
    rng = np.random.default_rng(seed)
    x = MODEL.nominal_x()
    for name in PAPER_30:
        x[INDEX[name]] += rng.normal() * (0.5 if unit_of(name) == "mm" else 1e-3)
    return x


def regular_configurations(rng: np.random.Generator, n: int) -> np.ndarray:
    """Inside the limits, away from the wrist (J5 = 0) and stretched-elbow singularities."""
    lim = robot.JointLimits()
    q = rng.uniform(lim.lower_deg + 3.0, lim.upper_deg - 3.0, (4 * n, 6))
    q = q[np.abs(q[:, 4]) > 10.0]
    elbow_deg = q[:, 1] + q[:, 2] + np.degrees(ik._DELTA) - 90.0
    q = q[np.abs(np.sin(np.radians(elbow_deg))) > np.sin(np.radians(15.0))]
    T = MODEL.fk(MODEL.nominal_x(), q, flange=True)
    T_bf = np.linalg.inv(MODEL.T_part_base(MODEL.nominal_x())) @ T
    wrist = T_bf[:, :3, 3] - 175.0 * T_bf[:, :3, 2]
    return q[np.hypot(wrist[:, 0], wrist[:, 1]) > 300.0][:n]


def pose_errors(T: np.ndarray, T_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dp = np.linalg.norm(T[:, :3, 3] - T_ref[:, :3, 3], axis=1)
    dR = np.swapaxes(T_ref[:, :3, :3], 1, 2) @ T[:, :3, :3]
    # small angles: the norm of the skew part (arccos of the trace bottoms out at 1e-8)
    w = np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]])
    return dp, 0.5 * np.linalg.norm(w, axis=0)


def test_the_identified_robot_reaches_the_intended_pose_at_the_compensated_joints() -> None:
    x = perturbed_x(1)
    q = regular_configurations(np.random.default_rng(2), 200)
    c = compensate_joints(MODEL, x, q)
    assert c.ok.all(), set(c.reason)
    assert np.array_equal(c.q_nominal_deg, q)
    dp, ang = pose_errors(MODEL.fk(x, c.q_deg), c.T_intended)
    assert dp.max() < 1e-6 and ang.max() < 1e-10
    miss_mm, _ = pose_errors(MODEL.fk(x, q), c.T_intended)
    assert np.median(miss_mm) > 1.0  # without compensation the real robot misses by mm
    assert 0.01 < np.median(c.joint_change_deg) < 2.0


def test_a_nominal_controller_lands_on_the_compensated_joints() -> None:
    x = perturbed_x(3)
    q = regular_configurations(np.random.default_rng(4), 100)
    c = compensate_joints(MODEL, x, q)
    assert c.ok.all()
    x0 = MODEL.nominal_x()
    assert np.abs(MODEL.fk(x0, c.q_deg) - c.T_command).max() < 1e-9
    sols = ik.solve(nominal_base_flange(MODEL, c.T_command), MODEL.limits)
    for i in range(len(q)):
        gap = np.abs(sols.for_pose(i) - c.q_deg[i]).max(axis=1).min()
        assert gap < 1e-8


def test_nominal_parameters_leave_the_targets_unchanged() -> None:
    q = regular_configurations(np.random.default_rng(5), 100)
    c = compensate_joints(MODEL, MODEL.nominal_x(), q)
    assert c.ok.all()
    assert np.abs(c.q_deg - q).max() < 1e-9


def test_pose_targets_keep_the_hinted_branch_or_follow_the_previous_row() -> None:
    x = perturbed_x(6)
    q = regular_configurations(np.random.default_rng(7), 50)
    by_joints = compensate_joints(MODEL, x, q)
    by_poses = compensate_poses(MODEL, x, by_joints.T_intended, q)
    assert np.abs(by_poses.q_deg - by_joints.q_deg).max() < 1e-9
    # a path without hints: each row stays on the branch of the previous one. J6 turns from
    # 150 to -150 deg in 10 deg steps; at the end its +360 alternative (210) is nearer the
    # start than the path (-150): a choice by the start alone would jump.
    path = np.repeat(q[:1], 31, axis=0)
    path[:, 5] = np.linspace(150.0, -150.0, 31)
    settings = CompensationSettings(start_q_deg=tuple(float(v) for v in path[0] + 2.0))
    q_nom, reasons = nominal_ik(MODEL, MODEL.fk(MODEL.nominal_x(), path), None, settings)
    assert not any(reasons)
    assert np.abs(q_nom - path).max() < 1e-8


def test_rows_that_cannot_be_compensated_say_why() -> None:
    x = perturbed_x(8)
    q = regular_configurations(np.random.default_rng(9), 3)
    T = MODEL.fk(MODEL.nominal_x(), q)
    T[1, :3, 3] += [4000.0, 0.0, 0.0]  # 4 m away: out of reach
    c = compensate_poses(MODEL, x, T, q)
    assert c.ok.tolist() == [True, False, True]
    assert "out of reach" in c.reason[1]
    assert np.isnan(c.q_deg[1]).all()
    # reachable, but only with J1 outside a narrowed range
    lim = robot.JointLimits(np.array([q[0, 0] + 5, -90, -160, -360, -125, -360.0]),
                            np.array([q[0, 0] + 20, 135, 280, 360, 125, 360.0]))  # fmt: skip
    narrow = SystemModel(MODEL.T_part_base_nominal, MODEL.T_flange_sensor_nominal, lim)
    c = compensate_poses(narrow, x, T[:1])
    assert not c.ok[0] and "within the joint limits" in c.reason[0]
    # the compensation moves the joints by more than allowed
    tight = CompensationSettings(max_joint_change_deg=1e-4)
    c = compensate_joints(MODEL, x, q, tight)
    assert not c.ok.any() and all("deg from the original joints" in r for r in c.reason)
