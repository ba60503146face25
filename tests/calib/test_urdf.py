"""The exported URDF, read by an independent library (yourdfpy), has the forward kinematics of
the identified model; with nominal parameters it is ROS-Industrial's M-710iC/50 chain, with the
current macro's `flange`; the joint_3 note."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from calib import robot
from calib.model import INDEX, PAPER_30, SystemModel, unit_of
from calib.transforms import pose, rotvec_to_matrix
from calib.urdf import JOINT_NAMES, controller_angles, urdf_angles, urdf_xml
from calib.wpr import matrix_from_rpy
from fakes.truth import URDF_AXES, URDF_XYZ_MM, TrueRobot

MODEL = SystemModel(
    pose(rotvec_to_matrix([0.01, -0.02, 0.3]), [2000.0, -300.0, 100.0]),
    pose(rotvec_to_matrix([0.2, -0.1, 0.5]), [10.0, 20.0, 150.0]),
)


#: tool0 in flange, ROS-I's link_6-tool0 origin rpy (pi, -pi/2, 0); and its inverse
TOOL0_IN_FLANGE = pose(matrix_from_rpy([np.pi, -np.pi / 2, 0.0]), np.zeros(3))
TOOL0_IN_FLANGE_INV = np.linalg.inv(TOOL0_IN_FLANGE)


def identified_x(seed: int) -> np.ndarray:
    """Every one of the 37 parameters off (the 30 identified ones and the other 7 too)."""
    rng = np.random.default_rng(seed)
    x = MODEL.nominal_x()
    for name in MODEL.names:
        scale = 0.5 if unit_of(name) == "mm" else 1e-3
        x[INDEX[name]] += rng.normal() * (scale if name in PAPER_30 else 0.1 * scale)
    return x


def load(tmp_path: Path, x: np.ndarray) -> yourdfpy.URDF:
    path = tmp_path / "robot.urdf"
    path.write_text(urdf_xml(MODEL, x), encoding="utf-8")
    return yourdfpy.URDF.load(str(path), load_meshes=False)


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    lim = robot.JointLimits()
    return rng.uniform(lim.lower_deg, lim.upper_deg, (n, 6))


def test_urdf_angles_couple_j3_to_j2() -> None:
    q = np.array([10.0, 20.0, -5.0, 40.0, -50.0, 60.0])
    u = np.degrees(urdf_angles(q))
    assert np.allclose(u, [10.0, 20.0, 15.0, 40.0, -50.0, 60.0])
    assert np.allclose(controller_angles(urdf_angles(q)), q)


@pytest.mark.parametrize("seed", [1, 2])
def test_urdf_forward_kinematics_equals_the_identified_model(tmp_path: Path, seed: int) -> None:
    x = identified_x(seed)
    urdf = load(tmp_path, x)
    assert urdf.validate()
    assert list(urdf.actuated_joint_names) == list(JOINT_NAMES)
    q = random_q(np.random.default_rng(seed + 10), 1000)
    T_sensor, T_flange = MODEL.fk(x, q), MODEL.fk(x, q, flange=True)
    err_mm, err_rot = 0.0, 0.0
    for i in range(len(q)):
        urdf.update_cfg(urdf_angles(q[i]))
        flange = T_flange[i] @ TOOL0_IN_FLANGE_INV
        for frame, T in (("sensor", T_sensor[i]), ("tool0", T_flange[i]), ("flange", flange)):
            Tu = urdf.get_transform(frame, "part")
            err_mm = max(err_mm, float(np.abs(1000.0 * Tu[:3, 3] - T[:3, 3]).max()))
            err_rot = max(err_rot, float(np.abs(Tu[:3, :3] - T[:3, :3]).max()))
    assert err_mm <= 1e-6
    assert err_rot <= 1e-12


def test_flange_and_tool0_as_in_the_current_ros_industrial_macro(tmp_path: Path) -> None:
    """fanuc_m710ic_support/urdf/m710ic50_macro.xacro since ros-industrial/fanuc 3b5a777:
    link_6 -> joint_6-flange (fixed, identity) -> flange -> link_6-tool0 (fixed, rpy (pi,
    -pi/2, 0)) -> tool0. The export had tool0 straight on link_6 (the older macro)."""
    for x in (MODEL.nominal_x(), identified_x(1)):
        urdf = load(tmp_path, x)
        flange, tool0 = urdf.joint_map["joint_6-flange"], urdf.joint_map["link_6-tool0"]
        assert (flange.type, flange.parent, flange.child) == ("fixed", "link_6", "flange")
        assert (tool0.type, tool0.parent, tool0.child) == ("fixed", "flange", "tool0")
        assert np.array_equal(flange.origin, np.eye(4))
        assert np.allclose(tool0.origin, TOOL0_IN_FLANGE, atol=1e-15)
        assert "joint_6-tool0" not in urdf.joint_map
    text = urdf_xml(MODEL, MODEL.nominal_x())
    note = text[text.index("<!-- joint_3") : text.index('<joint name="joint_3"')]
    assert "[-250, 415] deg" in note and "-160 <= u3 - u2 <= 280 deg" in note
    assert "34 % of the uniform samples" in note


def test_a_third_of_the_joint_3_box_breaks_the_controllers_j3_limit() -> None:
    """The figure of the joint_3 note: uniform samples of the URDF's joint_2 x joint_3 box."""
    lim = robot.JointLimits()
    rng = np.random.default_rng(0)
    u2 = rng.uniform(lim.lower_deg[1], lim.upper_deg[1], 200_000)
    u3 = rng.uniform(
        lim.lower_deg[1] + lim.lower_deg[2], lim.upper_deg[1] + lim.upper_deg[2], u2.size
    )
    j3 = u3 - u2
    broken = np.mean((j3 < lim.lower_deg[2]) | (j3 > lim.upper_deg[2]))
    assert abs(broken - 225.0 / 665.0) < 0.005


def test_nominal_export_is_the_ros_industrial_chain(tmp_path: Path) -> None:
    """Joint origins and axes as in fanuc_m710ic_support; FK equals the simulated cell's own
    URDF-style chain (fakes.truth, written independently) without errors."""
    urdf = load(tmp_path, MODEL.nominal_x())
    for j, (name, xyz, axis) in enumerate(zip(JOINT_NAMES, URDF_XYZ_MM, URDF_AXES, strict=True)):
        joint = urdf.joint_map[name]
        assert np.allclose(joint.origin[:3, 3] * 1000.0, xyz, atol=1e-9), name
        assert np.allclose(joint.origin[:3, :3], np.eye(3), atol=1e-12), name
        assert np.array_equal(joint.axis, axis), name
        assert joint.parent == ("base_link" if j == 0 else f"link_{j}")
    truth = TrueRobot()
    q = random_q(np.random.default_rng(3), 200)
    T_true = truth.T_world_tool0(q)
    for i in range(len(q)):
        urdf.update_cfg(urdf_angles(q[i]))
        T = urdf.get_transform("tool0", "base")
        assert np.abs(1000.0 * T[:3, 3] - T_true[i, :3, 3]).max() < 1e-6
        assert np.abs(T[:3, :3] - T_true[i, :3, :3]).max() < 1e-12
