"""The kinematic model against an independent URDF chain, and its analytic Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from calib import robot
from calib.compliance import CompliantModel
from calib.model import (
    ALL_NAMES,
    COMPLIANCE_NAMES,
    INDEX,
    PAPER_30,
    SystemModel,
    group_of,
    unit_of,
)
from calib.transforms import (
    matrix_to_rotvec,
    pose,
    rot_z,
    rotvec_to_matrix,
    so3_right_jacobian,
)
from fakes.truth import TrueRobot
from tests.calib.reference_jacobian import reference_point_and_jacobian


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    lim = robot.JointLimits()
    return rng.uniform(lim.lower_deg, lim.upper_deg, (n, 6))


def test_nominal_fk_equals_independent_urdf_chain() -> None:
    rng = np.random.default_rng(0)
    q = random_q(rng, 10_000)
    model = SystemModel(np.eye(4), np.eye(4))
    T_model = model.fk(model.nominal_x(), q, flange=True)
    T_urdf = TrueRobot().T_world_tool0(q)
    assert np.abs(T_model[:, :3, 3] - T_urdf[:, :3, 3]).max() < 1e-9
    assert np.abs(T_model[:, :3, :3] - T_urdf[:, :3, :3]).max() < 1e-12


def test_home_pose_matches_reference() -> None:
    model = SystemModel(np.eye(4), np.eye(4))
    T = model.fk(model.nominal_x(), np.zeros((1, 6)), flange=True)[0]
    # REFERENCE.md: tool0 at (1341, 0, 1605) from base_link, World is 565 mm above it
    np.testing.assert_allclose(T[:3, 3], [1341.0, 0.0, 1605.0 - 565.0], atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)


def test_coupling_round_trip() -> None:
    q = np.random.default_rng(1).uniform(-100, 100, (50, 6))
    np.testing.assert_allclose(robot.theta_to_controller(robot.controller_to_theta(q)), q)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_analytic_jacobian_equals_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T_pb = pose(rotvec_to_matrix([0.1, -0.2, 1.4]), [1500.0, -2500.0, 700.0])
    T_fs = pose(rotvec_to_matrix([0.0, 1.5707, 0.3]), [10.0, -90.0, 160.0])
    model = SystemModel(T_pb, T_fs)
    x = model.nominal_x() + rng.normal(0.0, 1e-2, len(ALL_NAMES))
    q = random_q(rng, 40)
    c = rng.normal([0, 0, 130], 10.0, (40, 3))
    J = model.point_jacobian(x, q, c, ALL_NAMES).reshape(-1, len(ALL_NAMES))
    J_fd = np.zeros_like(J)
    for k in range(len(ALL_NAMES)):
        h = 1e-4 if unit_of(ALL_NAMES[k]) == "mm" else 1e-7
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        J_fd[:, k] = (model.points_part(xp, q, c) - model.points_part(xm, q, c)).ravel() / (2 * h)
    scale = np.linalg.norm(J_fd, axis=0)
    rel = np.abs(J - J_fd).max(axis=0) / scale
    assert rel.max() < 1e-6, dict(zip(ALL_NAMES, rel.round(9), strict=True))


@pytest.mark.parametrize("n", [1, 7, 3000])
def test_jacobian_in_link_frames_equals_the_former_part_frame_computation(n: int) -> None:
    """The link-frame Jacobian (chunks of JACOBIAN_CHUNK rows) against the former computation
    in the part frame (tests/calib/reference_jacobian.py): any parameter subset and order,
    off-nominal x, the rigid and the compliant model (deflected joint angles)."""
    rng = np.random.default_rng(n)
    T_pb = pose(rotvec_to_matrix([0.1, -0.2, 1.4]), [1500.0, -2500.0, 700.0])
    T_fs = pose(rotvec_to_matrix([0.0, 1.5707, 0.3]), [10.0, -90.0, 160.0])
    rigid = SystemModel(T_pb, T_fs)
    x = rigid.nominal_x() + rng.normal(0.0, 1e-2, len(ALL_NAMES))
    q = random_q(rng, n)
    c = rng.normal([0, 0, 130], 10.0, (n, 3))
    shuffled = tuple(rng.permutation(ALL_NAMES))
    for active in (ALL_NAMES, PAPER_30, shuffled[:9], ("rz_FS", "x_PB", "beta2"), ()):
        p, J = rigid.point_and_jacobian(x, q, c, active)
        p_ref, J_ref = reference_point_and_jacobian(rigid, x, q, c, active)
        assert J.shape == J_ref.shape == (n, 3, len(active))
        assert np.abs(p - p_ref).max() < 1e-9  # mm, points ~3000 mm from the part origin
        assert np.abs(J - J_ref).max(initial=0.0) <= 1e-12 * np.abs(J_ref).max(initial=1.0)
    compliant = CompliantModel.of(rigid)
    xc = compliant.nominal_x()
    xc[: len(ALL_NAMES)] = x
    xc[[INDEX[k] for k in COMPLIANCE_NAMES]] = [2e-4, 3e-4, -1e-4, 1e-4, 2e-4]
    p, J = compliant.point_and_jacobian(xc, q, c, PAPER_30)
    p_ref, J_ref = reference_point_and_jacobian(compliant, xc, q, c, PAPER_30)
    assert np.abs(p - p_ref).max() < 1e-9
    assert np.abs(J - J_ref).max() <= 1e-12 * np.abs(J_ref).max()


def test_rotvec_helpers() -> None:
    rng = np.random.default_rng(3)
    for r in rng.normal(0, 0.8, (20, 3)):
        np.testing.assert_allclose(matrix_to_rotvec(rotvec_to_matrix(r)), r, atol=1e-12)
        dr = rng.normal(0, 1e-7, 3)
        lhs = rotvec_to_matrix(r + dr)
        rhs = rotvec_to_matrix(r) @ rotvec_to_matrix(so3_right_jacobian(r) @ dr)
        assert np.abs(lhs - rhs).max() < 1e-12


def test_parameter_set_is_the_papers_thirty() -> None:
    assert len(PAPER_30) == 30 and len(set(PAPER_30)) == 30
    groups = [group_of(n) for n in PAPER_30]
    assert groups.count("part->base") == 6 and groups.count("flange->sensor") == 6
    assert groups.count("joint 1") == 2
    for j in (2, 3, 4, 5):
        assert groups.count(f"joint {j}") == 4
    assert unit_of("a2") == "mm" and unit_of("alpha2") == "rad" and unit_of("beta2") == "rad"
    assert unit_of("dtheta3") == "rad" and unit_of("d4") == "mm" and unit_of("rz_FS") == "rad"


def test_fk_batch_shape_and_no_mutation() -> None:
    model = SystemModel(pose(rot_z(0.3), [1.0, 2.0, 3.0]), np.eye(4))
    x = model.nominal_x()
    x_copy = x.copy()
    q = np.zeros((7, 6))
    assert model.fk(x, q).shape == (7, 4, 4)
    np.testing.assert_array_equal(x, x_copy)


def test_points_sensor_inverts_points_part() -> None:
    """A point fixed in the part frame, taken into each pose's sensor frame and back, is where
    it was; one point for many poses or one per pose."""
    rng = np.random.default_rng(5)
    model = SystemModel(pose(rot_z(0.3), [1.0, 2.0, 3.0]), pose(rot_z(0.1), [0.0, 0.0, 130.0]))
    x = model.nominal_x() + rng.normal(0.0, 1e-3, model.nominal_x().shape)
    q = random_q(rng, 5)
    p = rng.uniform(-500.0, 500.0, (5, 3))
    np.testing.assert_allclose(model.points_part(x, q, model.points_sensor(x, q, p)), p, atol=1e-9)
    one = model.points_sensor(x, q, p[0])
    np.testing.assert_allclose(model.points_part(x, q, one), np.tile(p[0], (5, 1)), atol=1e-9)
