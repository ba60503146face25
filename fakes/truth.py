"""The true robot of the simulated cell: a URDF-style chain with its own errors.

Deliberately independent of calib/: joint origins (xyz + roll-pitch-yaw) and joint axes as in
the ROS-Industrial `m710ic50_macro.xacro`, each origin perturbed by a seeded 6-DoF error, encoder
zero offsets, an unmodelled gravity compliance of J2 and J3, and thermal growth of the link
vectors with the cell temperature. An error in calib's model cannot hide behind this one.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]

#: URDF joint origins [mm] and axes (base_link -> link_6), then link_6 -> tool0 rpy.
URDF_XYZ_MM = np.array(
    [[0, 0, 565], [150, 0, 0], [0, 0, 870], [0, 0, 170], [1016, 0, 0], [175, 0, 0]], float
)
URDF_AXES = np.array([[0, 0, 1], [0, 1, 0], [0, -1, 0], [-1, 0, 0], [0, -1, 0], [-1, 0, 0]], float)
TOOL0_RPY_RAD = np.array([np.pi, -np.pi / 2, 0.0])
#: FANUC World frame above base_link [mm].
WORLD_Z_MM = 565.0
#: Link masses [kg] (upper arm, forearm with wrist, sensor) and gravity, for the compliance.
LINK_MASS_KG = (60.0, 45.0, 6.0)
GRAVITY_M_S2 = 9.81


def _rot_k(axis: F64) -> F64:
    """The cross-product matrix (3, 3) of a unit axis (3,)."""
    return np.array(
        [[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]], dtype=float
    )


def _rot(axis: F64, angle: F64) -> F64:
    """Rotations (..., 3, 3) about a unit axis (3,) by angles (...) [rad] (Rodrigues)."""
    K = _rot_k(axis)
    return _rodrigues(K, K @ K, angle)


def _rodrigues(K: F64, KK: F64, angle: ArrayLike) -> F64:
    """I + sin(a) K + (1 - cos(a)) K^2 for angles (...) [rad] and an axis's cross-product
    matrix K and its square KK (each (3, 3), or stacked to broadcast with the angles)."""
    a = np.asarray(angle, dtype=float)[..., None, None]
    out: F64 = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * KK
    return out


def _cross(a: F64, b: F64) -> F64:
    """a x b over the last axis, as np.cross computes it (a1 b2 - a2 b1, ...), without its
    overhead on small arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _rpy(rpy: ArrayLike) -> F64:
    r, p, y = np.asarray(rpy, dtype=float)
    X = _rot(np.array([1.0, 0, 0]), np.array(r))
    Y = _rot(np.array([0, 1.0, 0]), np.array(p))
    Z = _rot(np.array([0, 0, 1.0]), np.array(y))
    out: F64 = Z @ Y @ X
    return out


def homogeneous(R: F64, t: ArrayLike) -> F64:
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


@dataclass(frozen=True)
class TrueRobot:
    """A URDF chain with errors. `origin_xyz_mm` (6, 3), `origin_rpy_rad` (6, 3) are the joint
    origins; `zero_offset_rad` (6,) the encoder zero errors (URDF joint angle = controller
    mapping + offset); `compliance_rad_per_nm` (J2, J3); `expansion_per_k` the linear thermal
    expansion coefficient of the links, about `reference_temp_c`."""

    origin_xyz_mm: F64 = field(default_factory=lambda: URDF_XYZ_MM.copy())
    origin_rpy_rad: F64 = field(default_factory=lambda: np.zeros((6, 3)))
    zero_offset_rad: F64 = field(default_factory=lambda: np.zeros(6))
    compliance_rad_per_nm: tuple[float, float] = (0.0, 0.0)
    expansion_per_k: float = 0.0
    reference_temp_c: float = 20.0

    @staticmethod
    def perturbed(
        rng: np.random.Generator,
        *,
        origin_mm: float = 0.15,
        origin_rad: float = 2e-4,
        zero_rad: float = 4e-4,
        compliance_rad_per_nm: tuple[float, float] = (5e-8, 5e-8),
        expansion_per_k: float = 11.5e-6,
    ) -> TrueRobot:
        """A robot with seeded 6-DoF errors on every joint origin (standard deviations)."""
        return TrueRobot(
            origin_xyz_mm=URDF_XYZ_MM + rng.normal(0.0, origin_mm, (6, 3)),
            origin_rpy_rad=rng.normal(0.0, origin_rad, (6, 3)),
            zero_offset_rad=rng.normal(0.0, zero_rad, 6),
            compliance_rad_per_nm=compliance_rad_per_nm,
            expansion_per_k=expansion_per_k,
        )

    def rigid(self) -> TrueRobot:
        """The same robot with compliance and thermal growth switched off."""
        return replace(self, compliance_rad_per_nm=(0.0, 0.0), expansion_per_k=0.0)

    def urdf_angles(self, q_deg: ArrayLike) -> F64:
        """Controller angles (N, 6) [deg] -> URDF joint angles (N, 6) [rad] (q3 = J3 + J2)."""
        q = np.radians(np.atleast_2d(np.asarray(q_deg, dtype=float)))
        u = q.copy()
        u[:, 2] = q[:, 2] + q[:, 1]
        out: F64 = u + self.zero_offset_rad
        return out

    @functools.cached_property
    def _chain(self) -> tuple[F64, F64, F64, F64]:
        """What every pose shares: the joint origins' rotations (6, 3, 3), each joint axis's
        cross-product matrix K and K @ K (6, 3, 3) (`_rodrigues`'s) and
        tool0's rotation as a pose (4, 4)."""
        R = np.stack([_rpy(rpy) for rpy in self.origin_rpy_rad])
        K = np.stack([_rot_k(axis) for axis in URDF_AXES])
        return R, K, K @ K, homogeneous(_rpy(TOOL0_RPY_RAD), np.zeros(3))

    def link_frames(self, q_urdf: F64, temp_c: float) -> F64:
        """World-frame poses (N, 7, 4, 4) of link_1..link_6 and tool0 [mm]."""
        scale = 1.0 + self.expansion_per_k * (temp_c - self.reference_temp_c)
        n = q_urdf.shape[0]
        R, K, KK, tool0 = self._chain
        origins = homogeneous(R, self.origin_xyz_mm * scale)
        joints = homogeneous(_rodrigues(K, KK, q_urdf), np.zeros(3))  # (N, 6, 4, 4)
        T = np.broadcast_to(homogeneous(np.eye(3), [0, 0, -WORLD_Z_MM]), (n, 4, 4)).copy()
        frames = np.zeros((n, 7, 4, 4))
        for j in range(6):
            T = T @ origins[j] @ joints[:, j]
            frames[:, j] = T
        frames[:, 6] = T @ tool0
        return frames

    def T_world_tool0(self, q_deg: ArrayLike, temp_c: float = 20.0) -> F64:
        """Flange poses (N, 4, 4) in the World frame, with gravity deflection of J2, J3."""
        q_u = self.urdf_angles(q_deg)
        frames = self.link_frames(q_u, temp_c)
        if any(self.compliance_rad_per_nm):
            q_u = q_u + self._deflection(frames)
            frames = self.link_frames(q_u, temp_c)
        out: F64 = frames[:, 6]
        return out

    def _deflection(self, frames: F64) -> F64:
        """Joint deflections (N, 6) [rad] of J2 and J3 under gravity (static, linear springs)."""
        o2, o3 = frames[:, 1, :3, 3], frames[:, 2, :3, 3]
        wrist, flange = frames[:, 4, :3, 3], frames[:, 6, :3, 3]
        m_up, m_fore, m_tool = LINK_MASS_KG
        # torque about a horizontal joint axis a through o of a mass m at c: ((c - o) x m g) . a
        g = np.array([0.0, 0.0, -GRAVITY_M_S2])
        masses_j3 = [(m_fore, 0.5 * (o3 + wrist)), (m_tool, flange)]
        masses_j2 = [(m_up, 0.5 * (o2 + o3)), *masses_j3]
        dq = np.zeros((frames.shape[0], 6))
        for col, origin, masses, axis_frame, k in (
            (1, o2, masses_j2, frames[:, 1], self.compliance_rad_per_nm[0]),
            (2, o3, masses_j3, frames[:, 2], self.compliance_rad_per_nm[1]),
        ):
            axis = axis_frame[:, :3, :3] @ URDF_AXES[col]
            tau = sum(
                np.einsum("ni,ni->n", _cross((c - origin) / 1000.0, m * g), axis) for m, c in masses
            )
            dq[:, col] = k * tau
        return dq


# -- the robot's repeatability ----------------------------------------------------------------
#: FANUC M-710iC/50 pose repeatability RP [mm], from FANUC's data sheet (M-710iC series,
#: "Repeatability +-0.07 mm", measured per ISO 9283).
M710IC50_RP_MM = 0.07
#: ISO 9283's RP = mean + 3 std of the distance l of the attained positions from their
#: barycentre. For an isotropic Gaussian error of sigma per axis, l / sigma follows the chi
#: distribution with 3 degrees of freedom: mean 2 sqrt(2 / pi), std sqrt(3 - 8 / pi), so
#: RP = 3.616 sigma.
RP_PER_SIGMA = 2.0 * np.sqrt(2.0 / np.pi) + 3.0 * np.sqrt(3.0 - 8.0 / np.pi)
#: The pose at which the data sheet's RP is taken to hold, controller angles [deg]: the middle of
#: the arm's working range (J2 = J3 = 0, the sensor looking down, the flange 1.17 m out and
#: 0.87 m up), where ISO 9283 puts its test cube.
RP_REFERENCE_DEG = (0.0, 0.0, 0.0, 0.0, -90.0, 0.0)


@dataclass(frozen=True)
class Repeatability:
    """The robot's non-repeatable pose error: where the arm stands after a move differs from
    where the controller put it, by a new random error at every stop (backlash, friction and
    the servo's settling act at the joints; the encoders report the commanded angles).

    Modelled at the joints: each physical joint angle (the URDF's, J3 not coupled to J2) is off
    by an independent Gaussian error of `joint_sigma_rad`, the same for every joint, drawn anew
    at every stop and the same for every frame of the sweep at that stop. The sigma comes from
    the data sheet's figure `rp_mm` (ISO 9283 RP, default M710IC50_RP_MM): at RP_REFERENCE_DEG
    the flange's attained positions have the data sheet's RP (`_rad_per_mm_at_reference`):
    sigma_q = 1.55e-5 rad (3.2 arcsec), the flange's error 14, 18 and 22 um RMS along x, y, z
    there (RP / RP_PER_SIGMA = 19.4 um, were it isotropic).

    Modelled at the joints rather than as a flange pose error, the error keeps the arm's
    kinematics: it grows with reach, and it turns the flange too (about 4e-5 rad RMS). The
    sensor sees the sphere 130 mm in front of it, about 300 mm from the flange, so the centre
    it measures moves with the flange's position error and with that turn: 15-34 um RMS per
    axis at the default cell's spheres (RP 0.08-0.11 mm there), 22 um per axis at the
    validation positions, a little more than the flange's. rp_mm = 0: a perfectly repeating
    robot."""

    rp_mm: float = M710IC50_RP_MM

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rp_mm) and self.rp_mm >= 0):
            raise ValueError("repeatability rp_mm must be >= 0")

    @property
    def joint_sigma_rad(self) -> float:
        """The standard deviation [rad] of each physical joint's error at a stop."""
        return self.rp_mm * _rad_per_mm_at_reference()

    def draw_deg(self, rng: np.random.Generator, n: int = 1) -> F64:
        """The errors (n, 6) of n stops as controller-angle offsets [deg] (J3's includes J2's
        coupling: a physical J2 error alone leaves the URDF's J3 angle in place)."""
        return controller_offsets_deg(rng.normal(0.0, self.joint_sigma_rad, (n, 6)))


def controller_offsets_deg(du_rad: ArrayLike) -> F64:
    """Controller-angle offsets (..., 6) [deg] of physical (URDF) joint offsets [rad]:
    the URDF's q3 = J3 + J2, so J3's offset is du3 - du2."""
    du = np.asarray(du_rad, dtype=float)
    out: F64 = np.degrees(du)
    out[..., 2] = np.degrees(du[..., 2] - du[..., 1])
    return out


@functools.cache
def _rad_per_mm_at_reference() -> float:
    """The joint sigma [rad] per mm of RP: 1 / RP of the flange's positions at RP_REFERENCE_DEG
    for unit joint errors, through the nominal chain's position Jacobian J (3, 6) with respect
    to the physical joint angles (central differences; the errors are small, so linear), RP
    evaluated as ISO 9283 does on 100 000 seeded stops."""
    robot = TrueRobot()
    q = np.asarray(RP_REFERENCE_DEG, dtype=float)
    h = 1e-6
    du = controller_offsets_deg(np.vstack([h * np.eye(6), -h * np.eye(6)]))
    p = robot.T_world_tool0(q + du)[:, :3, 3]
    J = (p[:6] - p[6:]).T / (2 * h)
    e = np.random.default_rng(9283).normal(0.0, 1.0, (100_000, 6)) @ J.T
    distance = np.linalg.norm(e - e.mean(axis=0), axis=1)
    return float(1.0 / (distance.mean() + 3.0 * distance.std()))


# -- the cell's truth over time ---------------------------------------------------------------
@dataclass(frozen=True)
class Warmup:
    """First-order warm-up of the cell: the temperature rises by ``rise_k`` [K] towards its
    asymptote with time constant ``tau_s`` [sim s] from ``start_s``: about +7.6 K after 3 h with
    the defaults (95 % of 8 K at three time constants)."""

    rise_k: float = 8.0
    tau_s: float = 3600.0
    start_s: float = 0.0

    def __post_init__(self) -> None:
        if not (self.tau_s > 0 and np.isfinite(self.rise_k)):
            raise ValueError("warm-up needs tau_s > 0 and a finite rise_k")

    def delta_k(self, t_s: float) -> float:
        """Temperature above ambient [K] at sim time t_s."""
        dt = max(t_s - self.start_s, 0.0)
        return float(self.rise_k * -np.expm1(-dt / self.tau_s))


#: "joint" is the J2 zero (as J2); Jn any axis's zero; "sphere" one sphere alone
JOINT_KNOCKS = ("J1", "J2", "J3", "J4", "J5", "J6")
KNOCK_KINDS = ("sensor", "fixture", "joint", *JOINT_KNOCKS, "sphere")
#: a simulated shift without a knock (`rvis experiment shift --knock none`)
NO_KNOCK = "none"


@dataclass(frozen=True)
class Knock:
    """A knock at sim time ``at_s`` of one rigid group of the true cell (``kind``):

    - ``sensor``: the sensor on its mount moves by ``shift_mm`` [mm] and tilts by ``tilt_deg``
      [deg] about its own origin (defaults 0.3 mm, 0.05 deg);
    - ``fixture``: the four spheres' frame (and so the part frame they define) moves by
      ``shift_mm`` and turns by ``tilt_deg`` about the spheres' centroid (0.5 mm, 0.03 deg);
    - ``joint`` (``J2``), ``J1`` .. ``J6``: that axis's encoder zero slips by ``tilt_deg``
      (0.01 deg; ``shift_mm`` unused);
    - ``sphere``: one sphere (drawn from the seed) moves alone by ``shift_mm`` (0.5 mm) in the
      part frame (its stand knocked; ``tilt_deg`` unused).

    Directions (and the slip's sign) are drawn from the seed passed to the methods."""

    at_s: float
    shift_mm: float = 0.3
    tilt_deg: float = 0.05
    kind: str = "sensor"

    def __post_init__(self) -> None:
        if self.kind not in KNOCK_KINDS:
            raise ValueError(f"knock kind must be one of {', '.join(KNOCK_KINDS)}")

    @staticmethod
    def of_kind(kind: str, at_s: float) -> Knock:
        """The issue's knock of each kind: sensor 0.3 mm / 0.05 deg, fixture 0.5 mm /
        0.03 deg, joint a J2 zero slip of 0.01 deg."""
        sizes = {"sensor": (0.3, 0.05), "fixture": (0.5, 0.03), "sphere": (0.5, 0.0)}
        sizes |= {k: (0.0, 0.01) for k in ("joint", *JOINT_KNOCKS)}
        if kind not in sizes:
            raise ValueError(f"knock kind must be one of {', '.join(KNOCK_KINDS)}")
        shift_mm, tilt_deg = sizes[kind]
        return Knock(at_s, shift_mm, tilt_deg, kind)

    def T_mount_knocked(self, rng: np.random.Generator) -> F64:
        """The knock as a pose (4, 4) in the sensor frame: T_sensorBefore_sensorAfter (the
        `sensor` kind; also the motion of the fixture about its centroid)."""
        direction = _unit_vector(rng)
        axis = _unit_vector(rng)
        R = _rot(axis, np.array(np.radians(self.tilt_deg)))
        return homogeneous(R, self.shift_mm * direction)

    def T_fixture_moved(self, rng: np.random.Generator, centroid_part_mm: ArrayLike) -> F64:
        """The `fixture` kind: T_partBefore_partAfter (4, 4), a shift and a turn about the
        spheres' centroid [mm, in the part frame before]."""
        c = np.asarray(centroid_part_mm, dtype=float)
        M = self.T_mount_knocked(rng)
        out: F64 = homogeneous(np.eye(3), c) @ M @ homogeneous(np.eye(3), -c)
        return out

    @property
    def axis(self) -> int | None:
        """The axis (0-5) whose zero slips; None: not a joint kind."""
        if self.kind == "joint":
            return 1
        return JOINT_KNOCKS.index(self.kind) if self.kind in JOINT_KNOCKS else None

    def zero_slip_rad(self, rng: np.random.Generator) -> F64:
        """A joint kind: the encoder zero offsets' change (6,) [rad] (its axis only)."""
        out = np.zeros(6)
        axis = 1 if self.axis is None else self.axis
        out[axis] = np.radians(self.tilt_deg) * (1.0 if rng.random() < 0.5 else -1.0)
        return out

    def sphere_moved(self, rng: np.random.Generator, targets: list[str]) -> tuple[str, F64]:
        """The `sphere` kind: which sphere and its move (3,) [mm, part frame]."""
        target = sorted(targets)[int(rng.integers(len(targets)))]
        return target, self.shift_mm * _unit_vector(rng)


def _unit_vector(rng: np.random.Generator) -> F64:
    v = rng.normal(0.0, 1.0, 3)
    out: F64 = v / np.linalg.norm(v)
    return out


# -- maintenance: changes beyond a knock (issue 41) ---------------------------------------------
MAINTENANCE_KINDS = ("sensor", "axis", "fixture")
#: the sizes a maintenance event draws when none is given: (shift [mm] low, high), (tilt or
#: zero [deg] low, high). A sensor of the same type on a new mount, a motor or encoder replaced
#: (the robot maker's remastering leaves the zero within a degree), a sphere fixture renewed.
MAINTENANCE_SIZES = {
    "sensor": ((2.0, 4.0), (0.1, 0.4)),
    "axis": ((0.0, 0.0), (0.2, 1.0)),
    "fixture": ((1.5, 3.0), (0.02, 0.08)),
}


@dataclass(frozen=True)
class Maintenance:
    """A maintenance event at world time ``at_s`` that changes the true cell beyond a knock:

    - ``sensor``: the sensor replaced by another of its type: a new mount pose on the flange
      (``shift_mm``, ``tilt_deg`` about the sensor's origin) and its own camera and laser
      (`replaced_sensor`: focal lengths, principal point, distortion, mirror axis and angle
      within the type's tolerances);
    - ``axis``: the motor or encoder of controller axis ``axis`` (1..6) replaced: its zero moves
      by ``tilt_deg`` (sign drawn), the gear unchanged (J2's zero moves the URDF's J3 with it);
    - ``fixture``: the sphere fixture renewed: the spheres move in the part frame (the body's
      frame, which the validation points keep), all of them by a rigid move of ``shift_mm`` and
      ``tilt_deg`` about their centroid, or, with ``sphere``, that one sphere replaced and
      standing ``shift_mm`` away from where it stood; with ``frame``, the fixture renewed moves
      the part frame itself against the robot's base by that rigid move (the spheres, the
      bodies and the validation points with it: a tracker registered to the fixture sees the
      spheres where they stood, the robot sees all of them moved).

    Sizes left None are drawn from the seed within `MAINTENANCE_SIZES`; directions and signs
    from the seed passed to the methods (the same seed, the same event in every process)."""

    at_s: float
    kind: str
    axis: int = 2
    sphere: str = ""
    shift_mm: float | None = None
    tilt_deg: float | None = None
    frame: bool = False

    def __post_init__(self) -> None:
        if self.kind not in MAINTENANCE_KINDS:
            raise ValueError(f"maintenance kind must be one of {', '.join(MAINTENANCE_KINDS)}")
        if not 1 <= self.axis <= 6:
            raise ValueError("maintenance axis must be 1..6")
        if self.frame and (self.kind != "fixture" or self.sphere):
            raise ValueError("frame: the whole fixture's renewal only (no sphere)")

    def sizes(self, rng: np.random.Generator) -> tuple[float, float]:
        """(shift [mm], tilt or zero change [deg]) of the event, drawn where not given."""
        (m_lo, m_hi), (d_lo, d_hi) = MAINTENANCE_SIZES[self.kind]
        mm, deg = rng.uniform(m_lo, m_hi), rng.uniform(d_lo, d_hi)
        return (
            float(mm if self.shift_mm is None else self.shift_mm),
            float(deg if self.tilt_deg is None else self.tilt_deg),
        )

    def pose_change(self, rng: np.random.Generator) -> F64:
        """The sensor's new mount relative to the old (4, 4), T_sensorOld_sensorNew (the
        ``sensor`` kind), or the spheres' rigid move about the origin (``fixture``)."""
        mm, deg = self.sizes(rng)
        return Knock(0.0, mm, deg).T_mount_knocked(rng)

    def zero_change_rad(self, rng: np.random.Generator) -> F64:
        """The ``axis`` kind: the URDF joint offsets' change (6,) [rad] of a controller zero
        moved by the event's size on its axis."""
        _, deg = self.sizes(rng)
        d = np.radians(deg) * (1.0 if rng.random() < 0.5 else -1.0)
        dq = np.zeros(6)
        dq[self.axis - 1] = d
        du = dq.copy()
        du[2] = dq[2] + dq[1]  # the URDF's q3 = J3 + J2
        return du

    def spheres_moved(
        self, rng: np.random.Generator, spheres_part_mm: dict[str, F64]
    ) -> dict[str, F64]:
        """The ``fixture`` kind: where each sphere stands after the renewal (part frame)."""
        out = {k: np.asarray(v, dtype=float).copy() for k, v in spheres_part_mm.items()}
        if self.sphere:
            if self.sphere not in out:
                raise ValueError(f"no sphere {self.sphere!r} in the cell")
            mm, _ = self.sizes(rng)
            out[self.sphere] = out[self.sphere] + mm * _unit_vector(rng)
            return out
        M = self.fixture_move(rng, np.mean(list(out.values()), axis=0))
        return {k: M[:3, :3] @ v + M[:3, 3] for k, v in out.items()}

    def fixture_move(self, rng: np.random.Generator, centroid_part_mm: ArrayLike) -> F64:
        """The ``fixture`` kind's rigid move (4, 4) in the part frame, about the spheres'
        centroid: where the spheres go, or (``frame``) T_partBefore_partAfter."""
        c = np.asarray(centroid_part_mm, dtype=float)
        out: F64 = homogeneous(np.eye(3), c) @ self.pose_change(rng) @ homogeneous(np.eye(3), -c)
        return out
