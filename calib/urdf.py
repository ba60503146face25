"""A URDF of the identified system: the ROS-Industrial M-710iC/50 chain whose forward
kinematics equals `SystemModel.fk(x, q)`.

Names as in the current ROS-Industrial `fanuc_m710ic_support` macro (`m710ic50_macro.xacro`
since ros-industrial/fanuc 3b5a777): links base_link, base (FANUC World), link_1..link_6,
flange, tool0; joints joint_1..joint_6, base_link-base, joint_6-flange (link_6 -> flange,
identity: the attachment point for end effectors) and link_6-tool0 (flange -> tool0, rpy
(pi, -pi/2, 0) nominally). rvis adds the root link `part` (the part frame, fixed joint
part-base_link) and `sensor` (fixed joint tool0-sensor). Lengths in metres, angles in radians,
as URDF wants.

**Joint angles** are URDF (ROS-I) angles, not controller angles: u = J for joints 1, 2, 4, 5,
6 and u3 = J3 + J2 (the controller's J3 is measured from the horizon; `urdf_angles`). The
controller enforces its J3 limit on J3 itself, which a URDF cannot say: joint_3 carries the
range J3 + J2 can take, [lo2 + lo3, hi2 + hi3], and a comment in the file says that a
planner must still check lo3 <= u3 - u2 <= hi3 (`j3_note`: 34 % of that box breaks it).

**How the identified model becomes URDF joints.** Modified-DH frame i of the model (after
Rz(theta_i + dtheta_i) Tz(d_i)) and ROS-I's link_i are attached to the same link; nominally
they differ by a constant C_i (a signed axis permutation plus a shift along the joint axis),
computed here from the nominal chain. The URDF's link_i is frame i times C_i, so with nominal
parameters the export is ROS-I's URDF (meshes of fanuc_m710ic_support fit), and with the
identified ones each joint origin is C_{i-1}^-1 Rx(alpha) Tx(a) [Ry(beta2)] Tz(d) Rz(offset +
dtheta) C_i: the joint zero offsets are folded into the origins, the axes stay ROS-I's. A shift
of C_i along the joint axis commutes with the joint rotation, which is why this is exact.
base_link is defined 565 mm below the identified base frame (FANUC World) along its z axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.etree import ElementTree as ET

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import robot
from calib.model import CHAIN, INDEX, SystemModel, elementary
from calib.transforms import inverse, pose, rot_z
from calib.wpr import rpy_from_matrix

F64 = NDArray[np.float64]

#: ROS-I joint origins [mm] (rpy all zero) and axes, base_link -> link_6 (REFERENCE.md).
ROSI_XYZ_MM = np.array(
    [[0, 0, 565], [150, 0, 0], [0, 0, 870], [0, 0, 170], [1016, 0, 0], [175, 0, 0]], float
)
ROSI_AXES = np.array([[0, 0, 1], [0, 1, 0], [0, -1, 0], [-1, 0, 0], [0, -1, 0], [-1, 0, 0]], float)
LINK_NAMES = ("base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6")
JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 7))

#: u = URDF_FROM_CONTROLLER @ J: the coupled URDF joint 3 is J3 + J2.
URDF_FROM_CONTROLLER = np.eye(6)
URDF_FROM_CONTROLLER[2, 1] = 1.0


def urdf_angles(q_deg: ArrayLike) -> F64:
    """Controller angles (..., 6) [deg] -> URDF joint angles (..., 6) [rad]."""
    u: F64 = np.radians(np.asarray(q_deg, dtype=float)) @ URDF_FROM_CONTROLLER.T
    return u


def controller_angles(u_rad: ArrayLike) -> F64:
    """URDF joint angles (..., 6) [rad] -> controller angles (..., 6) [deg]."""
    q: F64 = np.degrees(np.asarray(u_rad, dtype=float) @ np.linalg.inv(URDF_FROM_CONTROLLER).T)
    return q


def _theta_of_urdf() -> tuple[F64, F64]:
    """(sign s, offset [rad]) with MDH theta_i = s_i u_i + offset_i."""
    S = robot.COUPLING @ np.linalg.inv(URDF_FROM_CONTROLLER)
    if not np.allclose(S, np.diag(np.diag(S))):
        raise AssertionError("the URDF angles do not map joint by joint onto the MDH ones")
    return np.diag(S).copy(), robot.THETA_OFFSET_RAD.copy()


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: origin (4, 4) [mm] in the parent link, axis (3,) (None: fixed)."""

    name: str
    parent: str
    child: str
    origin: F64
    axis: F64 | None = None
    lower_rad: float = 0.0
    upper_rad: float = 0.0
    velocity_rad_s: float = 0.0


def _joint_blocks(x: F64) -> list[F64]:
    """A_i (i = 1..6): frame i-1 -> frame i of the model at URDF angle 0, Rz(offset + dtheta)
    included (a joint's Tz(d) commutes with its rotation, so it comes first)."""
    _, offset = _theta_of_urdf()
    blocks, M, joint = [], np.eye(4), 0
    for kind, name, _ in CHAIN[1:-1]:
        if kind == "rz":
            rz = pose(rot_z(offset[joint] + x[INDEX[name]]), np.zeros(3))
            d = elementary("tz", x[INDEX[f"d{joint + 1}"]])
            blocks.append(M @ d @ rz)
            M, joint = np.eye(4), joint + 1
        elif kind != "tz":
            M = M @ elementary(kind, x[INDEX[name]])
    return blocks


def _rosi_frames(u_rad: F64) -> list[F64]:
    """ROS-I link_1..link_6 in base_link at URDF angles u (6,)."""
    frames, T = [], np.eye(4)
    for j in range(6):
        T = (
            T
            @ pose(np.eye(3), ROSI_XYZ_MM[j])
            @ pose(_axis_rotation(ROSI_AXES[j], u_rad[j]), np.zeros(3))
        )
        frames.append(T)
    return frames


def _axis_rotation(axis: F64, angle: float) -> F64:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R: F64 = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
    return R


def link_offsets(model: SystemModel) -> list[F64]:
    """C_0..C_6: base_link in the base frame, then ROS-I link_i in model frame i (nominal),
    snapped to exact axis permutations and 1e-6 mm."""
    C0 = pose(np.eye(3), [0.0, 0.0, -robot.BASE_LINK_TO_WORLD_Z_MM])
    s, _ = _theta_of_urdf()
    blocks = _joint_blocks(model.nominal_x())
    out, F = [C0], inverse(C0)  # F: model frame i in base_link
    for j, L in enumerate(_rosi_frames(np.zeros(6))):
        F = F @ blocks[j]
        C = inverse(F) @ L
        C[:3, :3] = np.round(C[:3, :3])
        C[:3, 3] = np.round(C[:3, 3], 6)
        if np.any(C[:2, 3] != 0.0) or not np.allclose(s[j] * C[2, :3], ROSI_AXES[j]):
            raise AssertionError(f"link_{j + 1} is not frame {j + 1} turned about its axis")
        out.append(C)
    return out


def urdf_joints(model: SystemModel, x: F64) -> list[UrdfJoint]:
    """The joints of the exported URDF, part -> sensor, for parameters x (37,)."""
    s, _ = _theta_of_urdf()
    C = link_offsets(model)
    lim = model.limits
    lo_u, hi_u = np.radians(lim.lower_deg), np.radians(lim.upper_deg)
    lo_u[2] = np.radians(lim.lower_deg[1] + lim.lower_deg[2])
    hi_u[2] = np.radians(lim.upper_deg[1] + lim.upper_deg[2])
    speed = np.radians(robot.JOINT_SPEED_DEG_S)
    joints = [
        UrdfJoint("part-base_link", "part", "base_link", model.T_part_base(x) @ C[0]),
        UrdfJoint("base_link-base", "base_link", "base", inverse(C[0])),
    ]
    for j, A in enumerate(_joint_blocks(x)):
        origin = inverse(C[j]) @ A @ C[j + 1]
        axis = s[j] * C[j + 1][2, :3]
        joints.append(
            UrdfJoint(JOINT_NAMES[j], LINK_NAMES[j], LINK_NAMES[j + 1], origin, axis,
                      float(lo_u[j]), float(hi_u[j]), float(speed[j]))
        )  # fmt: skip
    joints.append(UrdfJoint("joint_6-flange", "link_6", "flange", np.eye(4)))
    joints.append(UrdfJoint("link_6-tool0", "flange", "tool0", inverse(C[6])))
    joints.append(UrdfJoint("tool0-sensor", "tool0", "sensor", model.T_flange_sensor(x)))
    return joints


def j3_note(model: SystemModel) -> str:
    """The comment before joint_3: the coupled limit a URDF cannot carry, and the share of the
    joint_2 x joint_3 box that breaks it (w2 / (w2 + w3) for uniform samples, w the widths of
    the J2 and J3 ranges: 34 % for the M-710iC/50)."""
    lo, hi = model.limits.lower_deg, model.limits.upper_deg
    w2, w3 = hi[1] - lo[1], hi[2] - lo[2]
    return (
        " joint_3 is the coupled joint u3 = J3 + J2 (ROS-Industrial): its limits"
        f" [{lo[1] + lo[2]:g}, {hi[1] + hi[2]:g}] deg are the range J3 + J2 can take. The"
        f" controller limits J3 itself: a planner must also keep {lo[2]:g} <= u3 - u2 <="
        f" {hi[2]:g} deg (J3 = u3 - u2), which {100 * w2 / (w2 + w3):.0f} % of the uniform"
        " samples of the joint_2 x joint_3 box break. "
    )


def _num(v: float) -> str:
    return repr(float(v) + 0.0)  # shortest text that reads back to the same double; no -0.0


def urdf_xml(model: SystemModel, x: F64, robot_name: str = "fanuc_m710ic50_rvis") -> str:
    """The URDF document (text) of the identified system x."""
    root = ET.Element("robot", name=robot_name)
    root.append(ET.Comment(" generated by rvis export urdf: identified kinematics, no meshes "))
    links = ["part", *LINK_NAMES[:1], "base", *LINK_NAMES[1:], "flange", "tool0", "sensor"]
    for name in links:
        ET.SubElement(root, "link", name=name)
    for j in urdf_joints(model, x):
        if j.name == "joint_3":
            root.append(ET.Comment(j3_note(model)))
        el = ET.SubElement(
            root, "joint", name=j.name, type="fixed" if j.axis is None else "revolute"
        )
        xyz = " ".join(_num(v / 1000.0) for v in j.origin[:3, 3])
        rpy = " ".join(_num(v) for v in rpy_from_matrix(j.origin[:3, :3]))
        ET.SubElement(el, "origin", xyz=xyz, rpy=rpy)
        ET.SubElement(el, "parent", link=j.parent)
        ET.SubElement(el, "child", link=j.child)
        if j.axis is not None:
            ET.SubElement(el, "axis", xyz=" ".join(_num(v) for v in j.axis))
            ET.SubElement(el, "limit", lower=_num(j.lower_rad), upper=_num(j.upper_rad),
                          effort="0", velocity=_num(j.velocity_rad_s))  # fmt: skip
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
