"""The kinematic model of the whole chain part <- base <- joints <- flange <- sensor.

The chain (modified DH after Craig, with Hayati's beta on the parallel J2/J3 pair):

    T_part_sensor(q) = T_part_base
                       * prod_{i=1..6} [ Rx(alpha_{i-1}) Tx(a_{i-1}) (Ry(beta2) if i = 3)
                                         Rz(theta_i(q) + dtheta_i) Tz(d_i) ]
                       * T_flange_sensor

The 6-DoF pieces are a translation [mm] in the parent frame and a rotation R_nominal exp([r]x)
with a local rotation vector r [rad] (no Euler singularity). The model knows 37 parameters; the
default identified set is the paper's 30 (DESIGN.md section 2.1):

    part->base 6       x_PB y_PB z_PB [mm], rx_PB ry_PB rz_PB [rad]
    joint 1            a1 [mm], alpha1 [rad]         (d1, dtheta1, a0, alpha0: in the base)
    joint 2            dtheta2, d2, a2, alpha2
    joint 3            dtheta3, beta2 (replaces d3), a3, alpha3
    joint 4, joint 5   dtheta_i, d_i, a_i, alpha_i
    flange->sensor 6   x_FS y_FS z_FS [mm], rx_FS ry_FS rz_FS [rad]  (dtheta6, d6: in the sensor)

Parameter vectors `x` are full-length (37,); an `active` tuple of names selects what is
identified. Everything is vectorised over configurations on the leading axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import robot
from calib.transforms import (
    apply,
    inverse,
    pose,
    rot_x,
    rot_y,
    rotvec_to_matrix,
    skew,
    so3_right_jacobian,
)

F64 = NDArray[np.float64]

BASE_NAMES = ("x_PB", "y_PB", "z_PB", "rx_PB", "ry_PB", "rz_PB")
SENSOR_NAMES = ("x_FS", "y_FS", "z_FS", "rx_FS", "ry_FS", "rz_FS")


def _joint_names() -> tuple[str, ...]:
    names: list[str] = []
    for i in range(1, 7):
        names += [f"alpha{i - 1}", f"a{i - 1}"]
        if i == 3:
            names.append("beta2")
        names += [f"dtheta{i}", f"d{i}"]
    return tuple(names)


JOINT_NAMES = _joint_names()
ALL_NAMES: tuple[str, ...] = BASE_NAMES + JOINT_NAMES + SENSOR_NAMES
#: Extra parameters of the compliance- and temperature-aware model (calib.compliance), after
#: the 37 rigid ones: lumped gravity compliance [rad/m] of J2 and J3 per arm term, and the
#: linear thermal expansion coefficient of the arm lengths [1/K].
COMPLIANCE_NAMES = ("c2_upper", "c2_fore", "c3_fore", "c2_payload", "c3_payload")
THERMAL_NAMES = ("expansion_per_k",)
EXTRA_NAMES: tuple[str, ...] = COMPLIANCE_NAMES + THERMAL_NAMES
INDEX = {name: k for k, name in enumerate(ALL_NAMES + EXTRA_NAMES)}
_FS_T = slice(INDEX["x_FS"], INDEX["x_FS"] + 3)
_FS_R = slice(INDEX["rx_FS"], INDEX["rx_FS"] + 3)

#: The paper's 30 identifiable parameters (rank 30 checked numerically in the tests).
PAPER_30: tuple[str, ...] = (
    *BASE_NAMES,
    "a1",
    "alpha1",
    "dtheta2",
    "d2",
    "a2",
    "alpha2",
    "dtheta3",
    "beta2",
    "a3",
    "alpha3",
    "dtheta4",
    "d4",
    "a4",
    "alpha4",
    "dtheta5",
    "d5",
    "a5",
    "alpha5",
    *SENSOR_NAMES,
)


def unit_of(name: str) -> str:
    """'mm' for lengths, 'rad' for angles ('rad/m' and '1/K' for the extra parameters)."""
    if name in EXTRA_NAMES:
        return "1/K" if name in THERMAL_NAMES else "rad/m"
    if name in BASE_NAMES or name in SENSOR_NAMES:
        return "mm" if name[0] in "xyz" else "rad"
    return "mm" if name[0] in "ad" and not name.startswith(("alpha", "dtheta")) else "rad"


def group_of(name: str) -> str:
    """Which piece of the chain a parameter belongs to, for reports."""
    if name in EXTRA_NAMES:
        return "thermal" if name in THERMAL_NAMES else f"compliance J{name[1]}"
    if name in BASE_NAMES:
        return "part->base"
    if name in SENSOR_NAMES:
        return "flange->sensor"
    if name == "beta2":
        return "joint 3"
    return f"joint {int(name[-1])}"


# The elementary operations of the chain, in order: (kind, parameter name, joint index).
# kinds: "base", "sensor" (6-DoF pieces), "rx" "ry" "tx" "tz" (constant), "rz" (joint).
def _chain() -> tuple[tuple[str, str, int], ...]:
    ops: list[tuple[str, str, int]] = [("base", "", -1)]
    for i in range(1, 7):
        ops += [("rx", f"alpha{i - 1}", -1), ("tx", f"a{i - 1}", -1)]
        if i == 3:
            ops.append(("ry", "beta2", -1))
        ops += [("rz", f"dtheta{i}", i - 1), ("tz", f"d{i}", -1)]
    ops.append(("sensor", "", -1))
    return tuple(ops)


CHAIN = _chain()
_AXIS = {"rx": 0, "ry": 1, "rz": 2, "tx": 0, "tz": 2}


def elementary(kind: str, value: float) -> F64:
    """The 4x4 transform of one elementary operation of CHAIN (rx, ry, rz, tx, ty, tz) by
    `value` [rad or mm] (also what calib.urdf writes joint by joint)."""
    if kind == "rx":
        return pose(rot_x(value), np.zeros(3))
    if kind == "ry":
        return pose(rot_y(value), np.zeros(3))
    t = np.zeros(3)
    t[_AXIS[kind]] = value
    return pose(np.eye(3), t)


class _Pieces(NamedTuple):
    consts: tuple[F64, ...]
    elems: tuple[F64 | None, ...]  # per CHAIN[1:-1] operation, None for the joint rotations
    T_pb: F64
    T_fs: F64


@dataclass(frozen=True)
class SystemModel:
    """Nominal system: the robot's modified-DH geometry and the nominal 6-DoF pieces.

    `T_part_base_nominal` and `T_flange_sensor_nominal` (4, 4) [mm] give the translation
    nominals and the rotations the local rotation vectors perturb.
    """

    T_part_base_nominal: F64
    T_flange_sensor_nominal: F64
    limits: robot.JointLimits = field(default_factory=robot.JointLimits)
    name: str = "fanuc-m710ic50-mdh30"
    version: int = 1
    #: which model ("rigid" here; calib.compliance.CompliantModel: "compliant") and the
    #: names of its full parameter vector
    _last_constants: list[Any] = field(default_factory=list, init=False, repr=False, compare=False)
    kind: ClassVar[str] = "rigid"
    names: ClassVar[tuple[str, ...]] = ALL_NAMES

    def default_active(self, temp_c: F64 | None = None) -> tuple[str, ...]:
        """The parameters identified by default (the paper's 30; temperatures are unused)."""
        return PAPER_30

    def nominal_x(self) -> F64:
        """Full parameter vector (37,) at nominal."""
        x = np.zeros(len(ALL_NAMES))
        x[0:3] = self.T_part_base_nominal[:3, 3]
        x[_FS_T] = self.T_flange_sensor_nominal[:3, 3]
        for i in range(6):
            x[INDEX[f"alpha{i}"]] = robot.MDH_ALPHA_RAD[i]
            x[INDEX[f"a{i}"]] = robot.MDH_A_MM[i]
            x[INDEX[f"d{i + 1}"]] = robot.MDH_D_MM[i]
        return x

    # -- pieces -----------------------------------------------------------------------------
    def T_part_base(self, x: F64) -> F64:
        R = self.T_part_base_nominal[:3, :3] @ rotvec_to_matrix(x[3:6])
        return pose(R, x[0:3])

    def T_flange_sensor(self, x: F64) -> F64:
        R = self.T_flange_sensor_nominal[:3, :3] @ rotvec_to_matrix(x[_FS_R])
        return pose(R, x[_FS_T])

    def _constants(self, x: F64) -> list[F64]:
        """C0..C6 with T = C0 Rz(phi1) C1 ... Rz(phi6) C6, phi_i = theta_i + dtheta_i."""
        return list(self._pieces(x).consts)

    def _pieces(self, x: F64) -> _Pieces:
        """The x-dependent constants of the chain. The last x's are kept: a sequential update
        evaluates the chain several times at one x, and for one configuration building them
        is most of the cost."""
        key = x.tobytes()
        entry = self._last_constants[0] if self._last_constants else None
        if entry is not None and entry[0] == key:
            pieces: _Pieces = entry[1]
            return pieces
        pieces = self._build_pieces(x)
        self._last_constants[:] = [(key, pieces)]  # one atomic entry: safe across threads
        return pieces

    def _build_pieces(self, x: F64) -> _Pieces:
        T_pb, T_fs = self.T_part_base(x), self.T_flange_sensor(x)
        elems = tuple(
            None if kind == "rz" else elementary(kind, x[INDEX[name]])
            for kind, name, _ in CHAIN[1:-1]
        )
        consts: list[F64] = []
        M = T_pb
        for E in elems:
            if E is None:
                consts.append(M)
                M = np.eye(4)
            else:
                M = M @ E
        consts.append(M @ T_fs)
        return _Pieces(tuple(consts), elems, T_pb, T_fs)

    def joint_phi(self, x: F64, q_deg: ArrayLike) -> F64:
        """Rotation angles of the six z-rotations (..., 6) [rad]."""
        dtheta = x[[INDEX[f"dtheta{i}"] for i in range(1, 7)]]
        return robot.controller_to_theta(q_deg) + dtheta

    # -- forward kinematics -----------------------------------------------------------------
    def fk(self, x: F64, q_deg: ArrayLike, *, flange: bool = False) -> F64:
        """T_part_sensor (N, 4, 4) for controller angles q_deg (N, 6); with flange=True the
        pose of the flange frame instead (T_part_flange)."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        phi = self.joint_phi(x, q)
        consts = self._constants(x)
        if flange:
            consts[-1] = consts[-1] @ inverse(self.T_flange_sensor(x))
        c, s = np.cos(phi), np.sin(phi)
        M = np.broadcast_to(consts[0], (q.shape[0], 4, 4)).copy()
        for i in range(6):
            col0 = M[:, :, 0].copy()
            M[:, :, 0] = col0 * c[:, i, None] + M[:, :, 1] * s[:, i, None]
            M[:, :, 1] = M[:, :, 1] * c[:, i, None] - col0 * s[:, i, None]
            M = M @ consts[i + 1]
        return M

    def points_part(
        self,
        x: F64,
        q_deg: ArrayLike,
        c_sensor_mm: ArrayLike,
        temp_c: ArrayLike | None = None,
    ) -> F64:
        """Sphere centres in the part frame (N, 3): P_i = T_part_sensor(q_i) C_i. The rigid
        model has no thermal term: cell temperatures `temp_c` (N,) [degC] are ignored."""
        return apply(self.fk(x, q_deg), np.asarray(c_sensor_mm, dtype=float))

    # -- identification Jacobian ------------------------------------------------------------
    def point_jacobian(
        self,
        x: F64,
        q_deg: ArrayLike,
        c_sensor_mm: ArrayLike,
        active: Sequence[str],
        temp_c: ArrayLike | None = None,
    ) -> F64:
        """d P_i / d x_active, shape (N, 3, len(active)) [mm per mm or mm per rad]
        (`temp_c` is ignored, as in `points_part`)."""
        return self.point_and_jacobian(x, q_deg, c_sensor_mm, active, temp_c)[1]

    def point_and_jacobian(
        self,
        x: F64,
        q_deg: ArrayLike,
        c_sensor_mm: ArrayLike,
        active: Sequence[str],
        temp_c: ArrayLike | None = None,
    ) -> tuple[F64, F64]:
        """`points_part` and `point_jacobian` together (N, 3), (N, 3, L), cheaper than both."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        c_s = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (q.shape[0], 3))
        p = apply(self.fk(x, q), c_s)
        want = {name: j for j, name in enumerate(active)}
        J = np.zeros((q.shape[0], 3, len(active)))
        phi = self.joint_phi(x, q)
        c_phi, s_phi = np.cos(phi), np.sin(phi)
        pieces = self._pieces(x)
        T_pb = pieces.T_pb
        self._base_columns(J, want, x, T_pb, p)
        # The frame before each elementary operation is A @ P: A (N, 4, 4) changes only at
        # the joints, P (4, 4) collects the constant operations since the last joint.
        A = np.broadcast_to(T_pb, (q.shape[0], 4, 4)).copy()
        P = np.eye(4)
        for (kind, name, joint), E in zip(CHAIN[1:-1], pieces.elems, strict=True):
            if kind == "rz":
                A = A @ P
                P = np.eye(4)
            col = want.get(name)
            if col is not None:
                axis_p = A[:, :3, :3] @ P[:3, _AXIS[kind]]
                if kind[0] == "r":
                    origin = A[:, :3, :3] @ P[:3, 3] + A[:, :3, 3]
                    J[:, :, col] = cross(axis_p, p - origin)
                else:
                    J[:, :, col] = axis_p
            if kind == "rz":
                col0 = A[:, :, 0].copy()
                A[:, :, 0] = col0 * c_phi[:, joint, None] + A[:, :, 1] * s_phi[:, joint, None]
                A[:, :, 1] = A[:, :, 1] * c_phi[:, joint, None] - col0 * s_phi[:, joint, None]
            elif E is not None:
                P = P @ E
        A = A @ P
        self._sensor_columns(J, want, x, A, c_s)
        return p, J

    def _base_columns(self, J: F64, want: dict[str, int], x: F64, T_pb: F64, p: F64) -> None:
        R = T_pb[:3, :3]
        for k in range(3):
            if (col := want.get(BASE_NAMES[k])) is not None:
                J[:, k, col] = 1.0
        rot_cols = [want.get(n) for n in BASE_NAMES[3:]]
        if any(c is not None for c in rot_cols):
            p_b = apply(inverse(T_pb), p)
            D = -R @ skew(p_b) @ so3_right_jacobian(x[3:6])
            for k, col in enumerate(rot_cols):
                if col is not None:
                    J[:, :, col] = D[:, :, k]

    def _sensor_columns(self, J: F64, want: dict[str, int], x: F64, A: F64, c_s: F64) -> None:
        R_a = A[:, :3, :3]
        for k in range(3):
            if (col := want.get(SENSOR_NAMES[k])) is not None:
                J[:, :, col] = R_a[:, :, k]
        rot_cols = [want.get(n) for n in SENSOR_NAMES[3:]]
        if any(c is not None for c in rot_cols):
            R_fs = self._pieces(x).T_fs[:3, :3]
            D = -(R_a @ R_fs) @ skew(c_s) @ so3_right_jacobian(x[_FS_R])
            for k, col in enumerate(rot_cols):
                if col is not None:
                    J[:, :, col] = D[:, :, k]


def cross(a: F64, b: F64) -> F64:
    """a x b for (N, 3) arrays; np.cross costs ~20 us of overhead per call."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _batched_elementary(kind: str, value: F64 | float, n: int) -> F64:
    if kind == "rz":
        v = np.asarray(value, dtype=float)
        c, s = np.cos(v), np.sin(v)
        E = np.zeros((n, 4, 4))
        E[:, 0, 0], E[:, 0, 1], E[:, 1, 0], E[:, 1, 1] = c, -s, s, c
        E[:, 2, 2] = E[:, 3, 3] = 1.0
        return E
    return elementary(kind, float(value))


def check_active(active: Sequence[str], known: Sequence[str] = ALL_NAMES) -> tuple[str, ...]:
    """Validate a selection of parameter names against a model's `known` names; raises
    ValueError naming the unknown ones."""
    unknown = [n for n in active if n not in known]
    if unknown:
        raise ValueError(f"unknown model parameters: {', '.join(unknown)}")
    if len(set(active)) != len(active):
        raise ValueError("a model parameter is selected twice")
    return tuple(active)
