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
    _last_links: list[Any] = field(default_factory=list, init=False, repr=False, compare=False)
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

    def points_sensor(self, x: F64, q_deg: ArrayLike, p_part_mm: ArrayLike) -> F64:
        """Points fixed in the part frame, p_part_mm (N, 3) or (3,), in the sensor frame of
        each pose q_deg (N, 6): the inverse of `points_part` (N, 3)."""
        T = self.fk(x, q_deg)
        p = np.broadcast_to(np.asarray(p_part_mm, dtype=float), (len(T), 3))
        out: F64 = np.einsum("kji,kj->ki", T[:, :3, :3], p - T[:, :3, 3])
        return out

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
        """`points_part` and `point_jacobian` together (N, 3), (N, 3, L), cheaper than both.

        Link frames: F_l is the frame just after joint l's rotation (F_0 the robot base, the
        part->base pose) and p_l the point in it. Every elementary operation acts in a link's
        frame, about or along a constant axis u through a constant origin o of that frame, so
        its column is R_l (u x (p_l - o)) for a rotation and R_l u for a translation: one
        (3 m, 3) product with p_l for the m operations of a link, then R_l. The points p_l come
        backwards from the sensor, the rotations R_l forwards from the base, both as rows of
        N-vectors, in chunks of configurations that keep every temporary in cache."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        n = q.shape[0]
        c_s = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (n, 3))
        phi = self.joint_phi(x, q)
        links = self._jacobian_links(x, tuple(active))
        p = np.empty((n, 3))
        J = np.zeros((n, 3, len(active)))
        for a in range(0, n, JACOBIAN_CHUNK):
            b = min(a + JACOBIAN_CHUNK, n)
            _jacobian_chunk(links, phi[a:b], c_s[a:b], len(active), p[a:b], J[a:b])
        return p, J

    def _jacobian_links(self, x: F64, active: tuple[str, ...]) -> _Links:
        """The constant part of `point_and_jacobian` at x for `active` (the last one kept)."""
        key = (x.tobytes(), active)
        entry = self._last_links[0] if self._last_links else None
        if entry is not None and entry[0] == key:
            links: _Links = entry[1]
            return links
        links = _links(self._pieces(x), x, active)
        self._last_links[:] = [(key, links)]
        return links


class _Link(NamedTuple):
    """The columns of the operations in one link frame: J[:, :, cols] = R_l (K p_l + b)."""

    cols: NDArray[np.intp]  # (m,)
    K: F64  # (3 m, 3)
    b: F64  # (3 m,)


class _Links(NamedTuple):
    consts: tuple[F64, ...]  # C0..C6 (4, 4)
    L0: F64  # (4, 4): the base frame -> before joint 1's rotation (C0 = T_pb L0)
    T_pb: F64
    links: tuple[_Link | None, ...]  # link 0 (already in the part frame: R_0 = I) .. link 6


def _links(pieces: _Pieces, x: F64, active: tuple[str, ...]) -> _Links:
    want = {name: j for j, name in enumerate(active)}
    ops: list[list[tuple[int, bool, F64, F64]]] = [[] for _ in range(7)]  # col, rotation, u, o
    link, P, L0 = 0, np.eye(4), np.eye(4)
    for (kind, name, _), E in zip(CHAIN[1:-1], pieces.elems, strict=True):
        if kind == "rz":
            L0 = P if link == 0 else L0
            link, P = link + 1, np.eye(4)
        col = want.get(name)
        if col is not None:
            ops[link].append((col, kind[0] == "r", P[:3, _AXIS[kind]].copy(), P[:3, 3].copy()))
        if E is not None:
            P = P @ E
    # the sensor's pose in link 6 is P T_fs: its translations along the flange frame's axes,
    # its rotation vector's columns about the sensor origin (so3 right Jacobian)
    T_fs = pieces.T_fs
    Jr_fs = P[:3, :3] @ T_fs[:3, :3] @ so3_right_jacobian(x[_FS_R])
    o_fs = P[:3, :3] @ T_fs[:3, 3] + P[:3, 3]
    for k in range(3):
        if (col := want.get(SENSOR_NAMES[k])) is not None:
            ops[6].append((col, False, P[:3, k].copy(), np.zeros(3)))
        if (col := want.get(SENSOR_NAMES[3 + k])) is not None:
            ops[6].append((col, True, Jr_fs[:, k].copy(), o_fs))
    T_pb = pieces.T_pb
    R_pb, Jr_pb = T_pb[:3, :3], so3_right_jacobian(x[3:6])
    out: list[_Link | None] = []
    for ell, link_ops in enumerate(ops):
        base = ell == 0
        if base:  # link 0's frame is the constant part->base pose: columns in the part frame
            for k in range(3):
                if (col := want.get(BASE_NAMES[3 + k])) is not None:
                    link_ops.append((col, True, Jr_pb[:, k].copy(), np.zeros(3)))
        m = len(link_ops) + (3 if base else 0)
        K, b, cols = np.zeros((m, 3, 3)), np.zeros((m, 3)), []
        for i, (col, rotation, u, o) in enumerate(link_ops):
            cols.append(col)
            if rotation:
                K[i] = skew(u)
                b[i] = -np.cross(u, o)
            else:
                b[i] = u
            if base:
                K[i], b[i] = R_pb @ K[i], R_pb @ b[i]
        if base:  # the part->base translations: unit columns, exactly
            for k in range(3):
                if (col := want.get(BASE_NAMES[k])) is not None:
                    b[len(cols), k] = 1.0
                    cols.append(col)
        m = len(cols)
        out.append(_Link(np.array(cols, dtype=np.intp), K[:m].reshape(3 * m, 3), b[:m].reshape(-1))
                   if m else None)  # fmt: skip
    return _Links(pieces.consts, L0, T_pb, tuple(out))


#: Configurations per chunk of `point_and_jacobian` (every (3, chunk) temporary in cache).
JACOBIAN_CHUNK = 1024


def _jacobian_chunk(links: _Links, phi: F64, c_s: F64, n_cols: int, p: F64, J: F64) -> None:
    """Points p (n, 3) and Jacobian rows J (n, 3, L) of a chunk of configurations."""
    n = phi.shape[0]
    c, s = np.cos(phi).T, np.sin(phi).T  # (6, n) rows
    C = links.consts
    # backwards: p_6 = C6 c_s, p_{l-1} = C_{l-1} Rz(phi_l) p_l; p_0 in the base frame
    pts: list[F64 | None] = [None] * 7
    v = C[6][:3, :3] @ c_s.T + C[6][:3, 3:4]
    pts[6] = v
    for ell in range(6, 0, -1):
        w = np.empty((3, n))
        w[0] = c[ell - 1] * v[0] - s[ell - 1] * v[1]
        w[1] = s[ell - 1] * v[0] + c[ell - 1] * v[1]
        w[2] = v[2]
        T = C[ell - 1] if ell > 1 else links.L0
        v = T[:3, :3] @ w + T[:3, 3:4]
        pts[ell - 1] = v
    p_base = pts[0]
    assert p_base is not None
    T_pb = links.T_pb
    p[...] = (T_pb[:3, :3] @ p_base + T_pb[:3, 3:4]).T
    if n_cols == 0:
        return
    JT = np.zeros((n_cols, 3, n))
    last = max((ell for ell, lk in enumerate(links.links) if lk is not None), default=0)
    # forwards: R_1 = C0 Rz(phi_1), R_l = R_{l-1} C_{l-1} Rz(phi_l), as (3, 3, n)
    R = np.empty((3, 3, n))
    for ell in range(last + 1):
        lk = links.links[ell]
        if ell > 0:
            Rc = C[0][:3, :3] if ell == 1 else None
            if Rc is not None:
                a0, a1 = Rc[:, 0:1], Rc[:, 1:2]
                R[:, 2] = Rc[:, 2:3]
                R0 = a0 * c[0] + a1 * s[0]
                R[:, 1] = a1 * c[0] - a0 * s[0]
                R[:, 0] = R0
            else:
                R = np.matmul(C[ell - 1][:3, :3].T, R)  # R[i] <- C^T R[i]: rows of R C
                R0 = R[:, 0] * c[ell - 1] + R[:, 1] * s[ell - 1]
                R[:, 1] = R[:, 1] * c[ell - 1] - R[:, 0] * s[ell - 1]
                R[:, 0] = R0
        if lk is None:
            continue
        pt = pts[ell]
        assert pt is not None
        m = lk.cols.size
        W = (lk.K @ pt + lk.b[:, None]).reshape(m, 3, n)
        JT[lk.cols] = W if ell == 0 else np.einsum("ikn,okn->oin", R, W)
    J[...] = JT.transpose(2, 1, 0)


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
