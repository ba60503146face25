"""IK on the identified model: nominal closed form + a few damped Gauss-Newton steps."""

from __future__ import annotations

import numpy as np

from calib import ik, ik_refine, robot
from calib.model import INDEX, PAPER_30, SystemModel, unit_of
from calib.transforms import inverse, pose, rotvec_to_matrix

MODEL = SystemModel(
    pose(rotvec_to_matrix([0.01, -0.02, 0.3]), [2000.0, -300.0, 100.0]),
    pose(rotvec_to_matrix([0.0, 0.0, 0.5]), [10.0, 20.0, 150.0]),
)


def perturbed_x(seed: int) -> np.ndarray:
    """The 'real' robot: every one of the 30 parameters off by ~0.5 mm / 1 mrad (joint zero
    offsets included), plus d6 and dtheta6 (in the sensor pieces for identification)."""
    rng = np.random.default_rng(seed)
    x = MODEL.nominal_x()
    for name in PAPER_30:
        x[INDEX[name]] += rng.normal() * (0.5 if unit_of(name) == "mm" else 1e-3)
    return x


def regular_configurations(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random configurations inside the limits, away from the wrist and elbow singularities."""
    lim = robot.JointLimits()
    q = rng.uniform(lim.lower_deg + 3.0, lim.upper_deg - 3.0, (4 * n, 6))
    q = q[np.abs(q[:, 4]) > 10.0]
    elbow_deg = q[:, 1] + q[:, 2] + np.degrees(ik._DELTA) - 90.0  # 0 or 180: stretched
    q = q[np.abs(np.sin(np.radians(elbow_deg))) > np.sin(np.radians(15.0))]
    nominal = SystemModel(np.eye(4), np.eye(4))
    T = nominal.fk(nominal.nominal_x(), q, flange=True)
    wrist = T[:, :3, 3] - 175.0 * T[:, :3, 2]
    q = q[np.hypot(wrist[:, 0], wrist[:, 1]) > 300.0]  # off the J1 axis
    return q[:n]


def test_refinement_reaches_the_target_where_the_nominal_closed_form_misses() -> None:
    x = perturbed_x(1)
    rng = np.random.default_rng(2)
    q_true = regular_configurations(rng, 300)
    T_target = MODEL.fk(x, q_true)
    T_bf = inverse(MODEL.T_part_base(x)) @ T_target @ inverse(MODEL.T_flange_sensor(x))
    lim = robot.JointLimits()
    nominal = ik.solve(T_bf, robot.JointLimits(lim.lower_deg - 2.0, lim.upper_deg + 2.0))
    # start from the branch the target came from (nearest nominal solution)
    d = np.abs(nominal.q_deg - q_true[nominal.pose_index]).max(axis=1)
    q0 = np.zeros_like(q_true)
    best = np.full(len(q_true), np.inf)
    for k in np.argsort(-d):
        i = nominal.pose_index[k]
        if d[k] < best[i]:
            best[i], q0[i] = d[k], nominal.q_deg[k]
    assert np.all(best < 2.0)
    miss_mm = np.linalg.norm(MODEL.fk(x, q0)[:, :3, 3] - T_target[:, :3, 3], axis=1)
    assert np.median(miss_mm) > 0.5  # the nominal closed form misses by millimetres
    ref = ik_refine.refine(MODEL, x, T_target, q0, max_iter=5)
    assert ref.iterations <= 5 and ref.converged.all()
    assert ref.position_error_mm.max() < 1e-6 and ref.rotation_error_rad.max() < 1e-9
    T_ref = MODEL.fk(x, ref.q_deg)
    assert np.abs(T_ref[:, :3, 3] - T_target[:, :3, 3]).max() < 1e-6
    assert np.abs(ref.q_deg - q_true).max() < 1e-6  # back to the configuration it came from


def test_solve_on_model_every_branch() -> None:
    x = perturbed_x(3)
    q_true = regular_configurations(np.random.default_rng(4), 50)
    T_target = MODEL.fk(x, q_true)
    sols = ik_refine.solve_on_model(MODEL, x, T_target)
    assert np.all(np.isfinite(sols.q_deg))
    ok = sols.converged
    assert ok.mean() > 0.9
    T = MODEL.fk(x, sols.q_deg[ok])
    assert np.abs(T[:, :3, 3] - T_target[sols.pose_index[ok], :3, 3]).max() < 1e-6
    assert robot.JointLimits().contains(sols.q_deg[ok]).all()
    for i in range(len(q_true)):  # the true configuration is always among the converged
        q_i = sols.q_deg[ok & (sols.pose_index == i)]
        assert np.abs(q_i - q_true[i]).max(axis=1).min() < 1e-6


def test_sensor_target_puts_the_sphere_where_planned() -> None:
    R = rotvec_to_matrix(np.array([[0.3, -0.2, 1.0], [2.0, 0.1, 0.0]]))
    p = np.array([[1800.0, 200.0, -50.0], [1500.0, -400.0, 10.0]])
    c = np.array([[3.0, -5.0, 130.0], [0.0, 0.0, 125.0]])
    T = ik_refine.sensor_target(p, c, R)
    assert np.allclose(np.einsum("kij,kj->ki", inverse(T)[:, :3, :3], p) + inverse(T)[:, :3, 3], c)


def test_leaving_the_limits_is_not_converged() -> None:
    x = MODEL.nominal_x()
    q = np.array([[0.0, 0.0, 0.0, 0.0, -30.0, 0.0]])
    tight = robot.JointLimits(
        np.array([-180.0, -90.0, -160.0, -360.0, -125.0, 0.5]),
        np.array([180.0, 135.0, 280.0, 360.0, 125.0, 360.0]),
    )
    ref = ik_refine.refine(MODEL, x, MODEL.fk(x, q), q + 0.1, limits=tight)
    assert ref.position_error_mm[0] < 1e-6 and not ref.converged[0]
