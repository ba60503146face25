"""Configurations that put a sphere in the sensor's view (paper section 4.2).

A sensor pose that sees a sphere centre p: the sensor's z axis (its view direction) never points
upward, and the sensor origin sits so that the centre appears at c_sensor (ideally
(0, 0, 130) mm: working distance 120 + radius 15 - half depth of field 5). The flange pose
follows from the pre-calibrated hand-eye and part->base pieces of the model, the joint angles
from the closed-form inverse kinematics.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import ik
from calib.ik_refine import refine
from calib.model import SystemModel
from calib.transforms import apply, inverse, pose, rotvec_to_matrix

F64 = NDArray[np.float64]

#: The ideal sphere-centre position in the sensor frame [mm] (paper: 120 + 15 - 5).
IDEAL_STANDOFF_MM = 130.0


def look_rotations(view_dir: ArrayLike, roll_rad: ArrayLike) -> F64:
    """Rotations (K, 3, 3) whose z axis is view_dir (K, 3) and whose x axis is turned by roll
    about it from the horizontal reference."""
    z = np.atleast_2d(np.asarray(view_dir, dtype=float))
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    ref = np.where(np.abs(z[:, 2:3]) < 0.99, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    x0 = np.cross(ref, z)
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    y0 = np.cross(z, x0)
    roll = np.asarray(roll_rad, dtype=float).reshape(-1, 1)
    x = np.cos(roll) * x0 + np.sin(roll) * y0
    y = np.cross(z, x)
    R: F64 = np.stack([x, y, z], axis=2)
    return R


def random_view_directions(rng: np.random.Generator, n: int, max_tilt_deg: float = 90.0) -> F64:
    """n unit view directions uniform over the downward cap within max_tilt_deg of straight
    down (z component <= 0: the sensor never looks upward)."""
    cos_max = np.cos(np.radians(max_tilt_deg))
    cz = rng.uniform(cos_max, 1.0, n)
    az = rng.uniform(-np.pi, np.pi, n)
    sz = np.sqrt(1.0 - cz**2)
    out: F64 = np.column_stack([sz * np.cos(az), sz * np.sin(az), -cz])
    return out


def flange_poses(
    model: SystemModel, x: F64, p_part_mm: ArrayLike, R_base_sensor: F64, c_sensor_mm: ArrayLike
) -> F64:
    """Flange poses T_base_flange (K, 4, 4) that put the sphere centre p_part_mm at
    c_sensor_mm (K, 3) in a sensor with orientation R_base_sensor (K, 3, 3)."""
    p_base = apply(inverse(model.T_part_base(x)), np.asarray(p_part_mm, dtype=float))
    c = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (R_base_sensor.shape[0], 3))
    origin = p_base - np.einsum("kij,kj->ki", R_base_sensor, c)
    T_base_sensor = pose(R_base_sensor, origin)
    out: F64 = T_base_sensor @ inverse(model.T_flange_sensor(x))
    return out


@dataclass(frozen=True)
class ViewSample:
    """Configurations (n, 6) [deg] and where the sphere should appear (n, 3) [mm]."""

    q_deg: F64
    c_planned_mm: F64


#: a random view's closed-form configuration is refined on the model where it misses the view
#: by more than this [mm]: within, the sphere is well inside the measuring volume's +-5 mm
REFINE_ABOVE_MM = 2.0


def random_configurations(
    model: SystemModel,
    x: F64,
    p_part_mm: ArrayLike,
    n: int,
    rng: np.random.Generator,
    *,
    max_offset_mm: tuple[float, float, float] = (10.0, 7.0, 2.0),
    max_tilt_deg: float = 75.0,
    max_tries: int = 200,
) -> ViewSample:
    """n random reachable configurations that see the sphere: random downward view, roll and
    offset in the field of view, one IK branch picked at random, refined on the model x
    (`calib.ik_refine`). Fewer when unreachable."""
    qs: list[F64] = []
    cs: list[F64] = []
    for _ in range(max_tries):
        if len(qs) >= n:
            break
        k = 4 * n
        views = random_view_directions(rng, k, max_tilt_deg)
        R = look_rotations(views, rng.uniform(-np.pi, np.pi, k))
        c = rng.uniform(-1.0, 1.0, (k, 3)) * np.asarray(max_offset_mm)
        c[:, 2] += IDEAL_STANDOFF_MM
        F = flange_poses(model, x, p_part_mm, R, c)
        sols = ik.solve(F, model.limits)
        for i in rng.permutation(k):
            options = sols.for_pose(int(i))
            if len(options) and len(qs) < n:
                q = _on_model(model, x, F[i], options[rng.integers(len(options))])
                if q is not None:
                    qs.append(q)
                    cs.append(c[i])
    return ViewSample(np.array(qs).reshape(-1, 6), np.array(cs).reshape(-1, 3))


def _on_model(model: SystemModel, x: F64, T_base_flange: F64, q_deg: F64) -> F64 | None:
    """The closed form's configuration q_deg of a flange pose, on the model x: the closed form
    is the nominal robot's; where it misses the view on x by more than REFINE_ABOVE_MM (a cell
    with a zero a degree off sees the sphere centimetres away) it is refined on x (None: the
    refinement did not converge); within, it is kept as it is."""
    target = model.T_part_base(x) @ T_base_flange @ model.T_flange_sensor(x)
    miss = np.linalg.norm(model.fk(x, q_deg[None])[0, :3, 3] - target[:3, 3])
    if miss <= REFINE_ABOVE_MM:
        return q_deg
    fit = refine(model, x, target, q_deg[None], max_iter=10)
    return fit.q_deg[0] if fit.converged[0] else None


def neighbour_configurations(
    model: SystemModel,
    x: F64,
    p_part_mm: ArrayLike,
    q_deg: ArrayLike,
    c_sensor_mm: ArrayLike,
    n: int,
    rng: np.random.Generator,
    *,
    tilt_deg: tuple[float, float] = (8.0, 20.0),
    max_tilt_deg: float = 75.0,
    max_joint_deg: float = 30.0,
    max_tries: int = 50,
) -> ViewSample:
    """n more views of the sphere at p_part_mm near the view q_deg (which sees it at
    c_sensor_mm): the sensor turned about the sphere's centre by tilt_deg (a random axis across
    the view direction, a random roll up to the same angle), the sphere where it was in the
    field of view, on the inverse kinematics branch nearest q_deg, no joint more than
    max_joint_deg from it (near a wrist singularity a small turn of the sensor is a half turn
    of J4 and J6). Each is a new stop of the robot a short motion away (a validation sphere
    measured from several views while it stays put). Fewer when unreachable or when the view
    would look up or tilt past max_tilt_deg."""
    q0 = np.asarray(q_deg, dtype=float)
    c = np.asarray(c_sensor_mm, dtype=float)
    T_base_part = inverse(model.T_part_base(x))
    R0 = (T_base_part @ model.fk(x, q0[None])[0])[:3, :3]
    qs: list[F64] = []
    cos_max = np.cos(np.radians(max_tilt_deg))
    for _ in range(max_tries):
        if len(qs) >= n:
            break
        a = np.cross(R0[:, 2], rng.normal(size=3))
        a *= np.radians(rng.uniform(*tilt_deg)) / np.linalg.norm(a)
        roll = np.radians(rng.uniform(-tilt_deg[1], tilt_deg[1]))
        R = rotvec_to_matrix(a) @ R0 @ rotvec_to_matrix(np.array([0.0, 0.0, roll]))
        if R[2, 2] > -cos_max:
            continue
        F = flange_poses(model, x, p_part_mm, R[None], c)
        options = ik.solve(F, model.limits).for_pose(0)
        if not len(options):
            continue
        nearest = options[int(np.argmin(np.max(np.abs(options - q0), axis=1)))]
        q = _on_model(model, x, F[0], nearest)
        if q is not None and np.max(np.abs(q - q0)) <= max_joint_deg:
            qs.append(q)
    return ViewSample(np.array(qs).reshape(-1, 6), np.tile(c, (len(qs), 1)))


# -- the candidate set of one sphere (paper section 4.2, step 2) ------------------------------

#: Where the sphere may appear in the field of view [mm, offsets from (0, 0, standoff)]: the
#: centre and four off-axis points (about half the half-field, depth +-2 mm). Off-axis views
#: make the sensor's roll about its optical axis observable (on the axis its column is zero).
FOV_SPREAD_MM: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (8.0, 5.0, 2.0),
    (-8.0, 5.0, -2.0),
    (8.0, -5.0, -2.0),
    (-8.0, -5.0, 2.0),
)
FOV_CENTRE_MM: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),)


@dataclass(frozen=True)
class ViewGrid:
    """Sensor orientations on a grid: the view direction (sensor z) at tilts 0..max_tilt from
    straight down in steps of step_deg, azimuths spaced step_deg along each tilt circle, and
    the roll about the view direction in steps of roll_step_deg (default step_deg). Each
    orientation takes the next of `offsets_mm` in turn (where the sphere appears)."""

    step_deg: float = 5.0
    max_tilt_deg: float = 80.0
    roll_step_deg: float | None = None
    offsets_mm: tuple[tuple[float, float, float], ...] = FOV_SPREAD_MM
    standoff_mm: float = IDEAL_STANDOFF_MM

    def __post_init__(self) -> None:
        if not 0.0 < self.step_deg <= 90.0:
            raise ValueError(f"grid step {self.step_deg} deg: expected 0 < step <= 90")
        if not 0.0 <= self.max_tilt_deg <= 90.0:
            raise ValueError(
                f"maximum tilt {self.max_tilt_deg} deg: the view direction must not point "
                "upward (0..90 deg from straight down)"
            )
        if not self.offsets_mm:
            raise ValueError("no field-of-view offsets given")

    def views(self) -> tuple[F64, F64]:
        """(R_base_sensor (K, 3, 3), c_sensor_mm (K, 3)) of the whole grid."""
        return _grid_views(
            self.step_deg,
            self.max_tilt_deg,
            self.roll_step_deg or self.step_deg,
            self.offsets_mm,
            self.standoff_mm,
        )


@functools.lru_cache(maxsize=8)
def _grid_views(
    step_deg: float,
    max_tilt_deg: float,
    roll_step_deg: float,
    offsets: tuple[tuple[float, float, float], ...],
    standoff_mm: float,
) -> tuple[F64, F64]:
    dirs: list[tuple[float, float, float]] = []
    n_tilt = int(np.floor(max_tilt_deg / step_deg + 1e-9))
    for i in range(n_tilt + 1):
        tilt = np.radians(i * step_deg)
        n_az = max(1, round(360.0 * np.sin(tilt) / step_deg))
        for az in np.linspace(0.0, 2.0 * np.pi, n_az, endpoint=False):
            dirs.append((np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)))
    rolls = np.radians(np.arange(0.0, 360.0 - 1e-9, roll_step_deg))
    d = np.repeat(np.array(dirs), rolls.size, axis=0)
    R = look_rotations(d, np.tile(rolls, len(dirs)))
    off = np.asarray(offsets, dtype=float)
    c = off[np.arange(R.shape[0]) % off.shape[0]] + np.array([0.0, 0.0, standoff_mm])
    # cached (the swarm asks for the same grid at every particle): shared, so read-only
    R.setflags(write=False)
    c.setflags(write=False)
    return R, c


@dataclass(frozen=True)
class Clearance:
    """Keep-out rule for a view: the sensor origin and the flange stay at least
    `above_sphere_mm` above the sphere centre (the stand is below it) and `above_floor_mm`
    above the base plate's top face at `floor_z_mm` (robot base frame)."""

    above_sphere_mm: float = 30.0
    floor_z_mm: float = -565.0
    above_floor_mm: float = 150.0

    def allows(self, z_base_mm: F64, sphere_z_base_mm: float) -> NDArray[np.bool_]:
        ok: NDArray[np.bool_] = (z_base_mm >= sphere_z_base_mm + self.above_sphere_mm) & (
            z_base_mm >= self.floor_z_mm + self.above_floor_mm
        )
        return ok


@dataclass(frozen=True)
class Candidates:
    """Candidate configurations of one sphere: controller angles q_deg (M, 6) and where the
    sphere then appears, c_sensor_mm (M, 3); p_part_mm (3,) the sphere."""

    p_part_mm: F64
    q_deg: F64
    c_sensor_mm: F64

    def __len__(self) -> int:
        return int(self.q_deg.shape[0])

    def take(self, rows: ArrayLike) -> Candidates:
        r = np.asarray(rows, dtype=int)
        return Candidates(self.p_part_mm, self.q_deg[r], self.c_sensor_mm[r])


def sphere_candidates(
    model: SystemModel,
    x: F64,
    p_part_mm: ArrayLike,
    grid: ViewGrid,
    *,
    clearance: Clearance | None = None,
) -> Candidates:
    """Every grid view of the sphere at p_part_mm that the robot reaches within its limits and
    that keeps the clearance: flange poses through the (pre-calibrated) part->base and
    hand-eye pieces of x, then the closed-form IK (one solution per branch, no whole-turn
    duplicates: they have the same Jacobian)."""
    clearance = clearance or Clearance()
    p = np.asarray(p_part_mm, dtype=float).reshape(3)
    R, c = grid.views()
    T_flange = flange_poses(model, x, p, R, c)
    p_base = apply(inverse(model.T_part_base(x)), p)
    sensor_z = p_base[2] - np.einsum("kj,kj->k", R[:, 2, :], c)
    ok = clearance.allows(sensor_z, float(p_base[2])) & clearance.allows(
        T_flange[:, 2, 3], float(p_base[2])
    )
    keep = np.nonzero(ok)[0]
    sols = ik.solve(T_flange[keep], model.limits, turn_alternatives=False)
    rows = keep[sols.pose_index]
    return Candidates(p, sols.q_deg, c[rows])
