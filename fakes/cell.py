"""The simulated cell: the true robot, part frame, sensor mount, spheres, tracker and sensor.

It knows the truth and is seeded. Its kinematics are `fakes.truth` (URDF chain), never calib's
model. Two ways to measure a sphere:

- geometric: `measure_point` returns the true centre in the sensor frame plus Gaussian noise;
- rendered: `render_sweep` (or `sweep_job(...).render(cell.sensor)`) renders the galvo sweep the
  true sensor (`fakes.render_sensor.TrueSensor`) records from the true pose; app/ measures the
  frames with vision/ (this module never imports vision/).

Both see the sphere from where the true robot *stands*, not where it was commanded: every stop
of the robot is off by a new pose error, its repeatability (`fakes.truth.Repeatability`, the
data sheet's ISO 9283 RP, `SimSettings.repeatability_mm`; 0: a perfectly repeating robot). A
measurement at explicit joints (`measure_point`, `sweep_job`) is a move there and a stop of its
own; the device fakes' World path (`set_joints_deg`, then `measure_target` or the camera's
`render_frame`) stops when the joints stop changing: one error for every frame of the sweep at
that stop, a new one after the next move, even back to the same joints (`attained_deg`). A
stop's error is seeded by the cell's seed, its joints (to 0.1 deg, as a frame's noise below) and
how many stops at those joints came before, so it does not depend on the moves elsewhere (a
resumed commissioning step stops as an uninterrupted one does). The truth's validation
measurements are stops too (`centres_from_stops`).

`render_frame` is the camera hook of the device fakes' World protocol: the frame the camera sees
at the current joints and the current galvo command. Its image noise is seeded by the frame
itself (the cell's seed, the joints, the mirror command, exposure and gain, and how many times
this cell rendered that frame before), not drawn from one stream: a frame never depends on how
many frames were grabbed before it, so a commissioning step resumed in a new process (killed
mid-step) renders the very frames an uninterrupted run renders (fakes/cell_camera.py).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fakes.cell_camera import CameraFrames, digest
from fakes.cell_spec import CellSpec, NotVisible, SimSettings
from fakes.clock import Clock
from fakes.render import (
    Frames,
    SweepTruth,
    default_sweep_commands,
    render_sphere_sweep,
)
from fakes.render_sensor import TrueSensor, default_true_sensor, replaced_sensor
from fakes.truth import (
    Knock,
    Maintenance,
    Repeatability,
    TrueRobot,
    Warmup,
    _rot,
    homogeneous,
)

F64 = NDArray[np.float64]

#: Mirror commands [V] of one measurement sweep: 24 frames over +-3.2 V put the stripe on a
#: sphere anywhere in the measuring volume about every 1.3 mm (bench/vision.py, tests).
SWEEP_FRAMES = 24
SWEEP_SPAN_V = 3.2


@dataclass(frozen=True, eq=False)
class SweepJob:
    """One galvo sweep as the cell records it, as plain data (picklable, so a process pool can
    render it): the true sphere centre in the sensor frame [mm], its true radius, the mirror
    commands [V] and the seed of this sweep's image noise. Rendering is deterministic."""

    c_sensor_mm: F64
    radius_mm: float
    commands_v: F64
    seed: tuple[int, ...]

    def render(
        self, sensor: TrueSensor, *, stripe_truth: bool = False
    ) -> tuple[Frames, F64, SweepTruth]:
        """Frames shape=(n, H, W) uint8, the commands [V] and the renderer's truth."""
        return render_sphere_sweep(
            self.c_sensor_mm,
            self.radius_mm,
            sensor,
            np.random.default_rng(list(self.seed)),
            commands_v=self.commands_v,
            stripe_truth=stripe_truth,
        )


def _small_pose(rng: np.random.Generator, sigma_mm: float, sigma_rad: float) -> F64:
    rv = rng.normal(0.0, sigma_rad, 3)
    angle = float(np.linalg.norm(rv))
    axis = rv / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    return homogeneous(_rot(axis, np.array(angle)), rng.normal(0.0, sigma_mm, 3))


class SimulatedCell:
    """The true cell. `temp_c` may be changed between measurements (thermal drift); with a
    timeline (`set_timeline`) the temperature and the sensor mount follow a clock instead."""

    def __init__(
        self, spec: CellSpec, settings: SimSettings | None = None, sensor: TrueSensor | None = None
    ) -> None:
        self.spec = spec
        self._sensor = sensor
        self.settings = settings or SimSettings()
        rng = np.random.default_rng(self.settings.seed)
        robot = TrueRobot.perturbed(rng)
        if not self.settings.compliance:
            robot = replace(robot, compliance_rad_per_nm=(0.0, 0.0))
        if not self.settings.thermal:
            robot = replace(robot, expansion_per_k=0.0)
        self.robot = robot
        s = self.settings
        self.repeatability = Repeatability(s.repeatability_mm)
        self.T_part_world = spec.T_part_base @ _small_pose(rng, s.base_error_mm, s.base_error_rad)
        self._T_mount = spec.T_flange_sensor @ _small_pose(rng, s.mount_error_mm, s.mount_error_rad)
        self._ambient_c = s.temp_c
        self._clock: Clock | None = None
        self._world_s = 0.0  # the world's time at the clock's 0 (`set_timeline`)
        self.warmup: Warmup | None = None
        self.knock: Knock | None = None
        self._T_knock = np.eye(4)  # sensor knock: T_sensorBefore_sensorAfter
        self._T_part_knocked = self.T_part_world  # fixture knock: the part frame after it
        self._robot_knocked = robot  # joint knock: the robot after it
        self.maintenance: Maintenance | None = None  # a change beyond a knock (set_timeline)
        self._T_swap = np.eye(4)  # a sensor replaced: T_sensorOld_sensorNew
        self._zero_change_rad = np.zeros(6)  # a motor or encoder replaced: the URDF offsets
        self._robots: dict[tuple[bool, bool], TrueRobot] = {}  # (knocked, serviced) -> robot
        self._spheres_serviced: dict[str, F64] = {}  # a fixture renewed: the spheres after it
        self._T_part_serviced: F64 | None = None  # a fixture renewed moving the part frame
        self._sphere_knocked: tuple[str, F64] | None = None  # a sphere knocked alone
        self._sensor_serviced: TrueSensor | None = None  # a sensor replaced: the new one
        self._noise = np.random.default_rng([s.seed, 1])
        self._spheres = {k: np.asarray(v, dtype=float) for k, v in spec.spheres_part_mm.items()}
        self._q_deg = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
        self._lock = threading.Lock()  # device fakes call from their own threads
        self._stop_lock = threading.Lock()
        self._stops_seen: dict[int, int] = {}  # a stop's joints key -> stops there before
        self._moved = True  # the World path's joints changed since its stop was drawn
        self._stop_error_deg = np.zeros(6)  # the World path's current stop's error
        self._render_lock = threading.Lock()
        self._sweeps = 0  # sweeps handed out: the index in each sweep's noise seed
        # a new draw of every frame's noise (0: the first): a commissioning step run again
        # after it failed sees new noise, as a real camera's, where one resumed after a kill
        # (same draw) renders the frames of an uninterrupted run
        self.noise_draw = 0
        self.frames = CameraFrames(self, self._render_lock)  # what the camera sees
        self.sweep_commands_v = default_sweep_commands(SWEEP_FRAMES, SWEEP_SPAN_V)

    @property
    def sensor(self) -> TrueSensor:
        """The true sensor now (`sensor_at`)."""
        return self.sensor_at(None)

    def sensor_at(self, t_s: float | None) -> TrueSensor:
        """The true sensor at sim time t_s (default: now; camera + galvo laser; after a
        sensor's replacement the new one); its pixel rays take ~1 s on first use."""
        with self._render_lock:
            if self._sensor is None:
                self._sensor = default_true_sensor()
            m = self.maintenance
            if m is None or m.kind != "sensor" or not self._serviced(self._at(t_s)):
                return self._sensor
            if self._sensor_serviced is None:
                rng = np.random.default_rng([self.settings.seed, 6, 1])
                self._sensor_serviced = replaced_sensor(self._sensor, rng)
            return self._sensor_serviced

    # -- truth over time -------------------------------------------------------------------
    def set_timeline(
        self,
        clock: Clock,
        *,
        warmup: Warmup | None = None,
        knock: Knock | None = None,
        world_s: float = 0.0,
        maintenance: Maintenance | None = None,
    ) -> None:
        """Let the truth follow `clock`: the temperature warms up from the ambient `temp_c`,
        and at the knock its group moves (the sensor mount, the spheres' frame or the J2
        zero; its direction drawn from the cell's seed). world_s: the world's time at the
        clock's 0 (a line that continues an earlier run's world: warm and knocked as it left
        it). maintenance: a change beyond a knock at its time (`Maintenance`: a sensor replaced,
        an axis's zero moved, the spheres moved in the part frame; drawn from the cell's
        seed)."""
        self._clock, self.warmup, self.knock = clock, warmup, knock
        self._world_s = float(world_s)
        self._service(maintenance)
        rng = np.random.default_rng([self.settings.seed, 5])
        self._T_knock = np.eye(4)
        self._T_part_knocked, self._robot_knocked = self.T_part_world, self.robot
        self._sphere_knocked = None
        if knock is None:
            return
        if knock.kind == "sensor":
            self._T_knock = knock.T_mount_knocked(rng)
        elif knock.kind == "fixture":
            centroid = np.mean(list(self._spheres.values()), axis=0)
            moved = knock.T_fixture_moved(rng, centroid)
            self._T_part_knocked = np.linalg.inv(moved) @ self.T_part_world
        elif knock.kind == "sphere":
            self._sphere_knocked = knock.sphere_moved(rng, list(self._spheres))
        else:
            offsets = self.robot.zero_offset_rad + knock.zero_slip_rad(rng)
            self._robot_knocked = replace(self.robot, zero_offset_rad=offsets)

    def _service(self, maintenance: Maintenance | None) -> None:
        """Draw the maintenance event's change (seeded by the cell's seed alone)."""
        self.maintenance = maintenance
        self._T_swap, self._zero_change_rad = np.eye(4), np.zeros(6)
        self._spheres_serviced, self._sensor_serviced, self._robots = {}, None, {}
        self._T_part_serviced = None
        if maintenance is None:
            return
        rng = np.random.default_rng([self.settings.seed, 6])
        if maintenance.kind == "sensor":
            self._T_swap = maintenance.pose_change(rng)
        elif maintenance.kind == "axis":
            self._zero_change_rad = maintenance.zero_change_rad(rng)
        elif maintenance.frame:
            moved = maintenance.fixture_move(rng, np.mean(list(self._spheres.values()), axis=0))
            self._T_part_serviced = np.asarray(np.linalg.inv(moved), dtype=np.float64)
        else:
            self._spheres_serviced = maintenance.spheres_moved(rng, dict(self._spheres))

    def maintenance_truth(self) -> dict[str, object]:
        """What the maintenance event changed, as the truth knows it (for reports and tests):
        the sensor mount's shift [mm] and tilt [deg] and how far it moves a sphere at the
        standoff [mm], each controller axis's zero change [deg],
        each sphere's move [mm]; empty without an event."""
        m = self.maintenance
        if m is None:
            return {}
        R, t = self._T_swap[:3, :3], self._T_swap[:3, 3]
        tilt = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
        du = self._zero_change_rad
        dq = du.copy()
        dq[2] = du[2] - du[1]  # the controller's J3 of the URDF's q3 = J3 + J2
        moved = {
            k: float(np.linalg.norm(v - self._spheres[k]))
            for k, v in self._spheres_serviced.items()
        }
        v = self.spec.volume
        c = np.array([0.0, 0.0, 0.5 * (v.z_min_mm + v.z_max_mm)])  # a sphere at the standoff
        return {
            "kind": m.kind,
            "at_s": m.at_s,
            "mount_shift_mm": float(np.linalg.norm(t)),
            "mount_at_standoff_mm": float(np.linalg.norm(R @ c + t - c)),
            "mount_tilt_deg": tilt,
            "zero_change_deg": np.degrees(dq).tolist(),
            "spheres_moved_mm": moved,
            "frame_moved_mm": self._frame_moved_mm(),
        }

    def _frame_moved_mm(self) -> dict[str, float]:
        """How far a fixture renewal that moved the part frame moved each sphere against the
        robot's base [mm] (empty: the frame stayed)."""
        if self._T_part_serviced is None:
            return {}
        M = np.linalg.inv(self._T_part_serviced)  # T_partBefore_partAfter
        return {
            k: float(np.linalg.norm(M[:3, :3] @ v + M[:3, 3] - v)) for k, v in self._spheres.items()
        }

    def _knocked(self, t_world_s: float) -> bool:
        return self.knock is not None and t_world_s >= self.knock.at_s

    def _serviced(self, t_world_s: float) -> bool:
        return self.maintenance is not None and t_world_s >= self.maintenance.at_s

    def _robot_at(self, t_world_s: float) -> TrueRobot:
        """The true robot at world time t: knocked, its axis serviced, or as built."""
        key = (self._knocked(t_world_s), self._serviced(t_world_s))
        robot = self._robots.get(key)
        if robot is None:
            robot = self._robot_knocked if key[0] else self.robot
            if key[1] and np.any(self._zero_change_rad):
                offsets = robot.zero_offset_rad + self._zero_change_rad
                robot = replace(robot, zero_offset_rad=offsets)
            self._robots[key] = robot
        return robot

    def now_s(self) -> float:
        """The cell's sim time [s] (0 without a timeline)."""
        return 0.0 if self._clock is None else self._clock.monotonic()

    def _at(self, t_s: float | None) -> float:
        """The world's time [s] at sim time t_s (default: now): the warm-up and the knock run on
        it; `world_s` ahead of the clock when a line continues an earlier run's world."""
        return (self.now_s() if t_s is None else float(t_s)) + self._world_s

    def temp_at(self, t_s: float | None = None) -> float:
        """The cell temperature [deg C] at sim time t_s (default: now)."""
        return self._temp(self._at(t_s))

    def _temp(self, t_world_s: float) -> float:
        warm = 0.0 if self.warmup is None else self.warmup.delta_k(t_world_s)
        return self._ambient_c + warm

    @property
    def temp_c(self) -> float:
        """The temperature now [deg C]; setting it sets the ambient the warm-up starts from."""
        return self.temp_at()

    @temp_c.setter
    def temp_c(self, value: float) -> None:
        self._ambient_c = float(value)

    def mount_at(self, t_s: float | None = None) -> F64:
        """The true sensor mount T_tool0_sensor (4, 4) at sim time t_s (default: now)."""
        return self._mount(self._at(t_s))

    def _mount(self, t_world_s: float) -> F64:
        out: F64 = self._T_mount.copy()
        if self._knocked(t_world_s):
            out = out @ self._T_knock
        if self._serviced(t_world_s):
            out = out @ self._T_swap
        return out

    @property
    def T_tool0_sensor(self) -> F64:
        return self.mount_at()

    # -- truth ---------------------------------------------------------------------------
    def T_part_sensor(self, q_deg: ArrayLike, t_s: float | None = None) -> F64:
        """True sensor poses (N, 4, 4) in the part frame for controller angles (N, 6) at sim
        time t_s (default: now)."""
        t = self._at(t_s)
        T_pw = self._T_part_knocked if self._knocked(t) else self.T_part_world
        if self._T_part_serviced is not None and self._serviced(t):
            T_pw = self._T_part_serviced @ T_pw  # T_partAfter_partBefore
        T_wt = self._robot_at(t).T_world_tool0(q_deg, self._temp(t))
        out: F64 = T_pw @ T_wt @ self._mount(t)
        return out

    def centre_in_sensor(
        self, q_deg: ArrayLike, p_part_mm: ArrayLike, t_s: float | None = None
    ) -> F64:
        """True sphere centres (N, 3) in the sensor frame at sim time t_s (default: now)."""
        T = self.T_part_sensor(q_deg, t_s)
        p = np.broadcast_to(np.asarray(p_part_mm, dtype=float), (T.shape[0], 3))
        R_t = np.swapaxes(T[:, :3, :3], 1, 2)
        out: F64 = np.einsum("nij,nj->ni", R_t, p - T[:, :3, 3])
        return out

    # -- instruments ---------------------------------------------------------------------
    def sees(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> bool:
        """Whether the sphere at p_part_mm lies in the measuring volume from q_deg."""
        return bool(self.sees_each(np.atleast_2d(q_deg)[:1], p_part_mm)[0])

    def sees_each(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> NDArray[np.bool_]:
        """`sees` for each of the configurations (N, 6) at once (N,)."""
        return np.asarray(self.spec.volume.contains(self.centre_in_sensor(q_deg, p_part_mm)))

    def _visible_centre(
        self, q_deg: ArrayLike, p_part_mm: ArrayLike, error_deg: F64 | None = None
    ) -> F64:
        """The true centre (3,) in S of the sphere at p_part_mm seen from a stop at q_deg
        (commanded) whose error is error_deg (default: a new stop there). Whether it is seen
        is the commanded pose's (`sees`): the measuring volume is a planning figure, and the
        stop's tens of um do not take a sphere out of it."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))[:1]
        c = self.centre_in_sensor(q, p_part_mm)[0]
        if not self.spec.volume.contains(c)[0]:
            raise NotVisible(f"sphere centre at {np.round(c, 1)} mm in the sensor frame")
        if error_deg is None:
            error_deg = self.new_stop_deg(q[0])
        out: F64 = self.centre_in_sensor(q + error_deg, p_part_mm)[0]
        return out

    def measure_point(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> F64:
        """One geometric sensor measurement (3,) [mm] of a sphere at p_part_mm from q_deg: a
        move there (a new stop, module docstring), the true centre from where the robot stands
        plus the sensor's noise; raises NotVisible outside the measuring volume."""
        return self._sensed(self._visible_centre(q_deg, p_part_mm))

    def _sensed(self, c_sensor_mm: F64) -> F64:
        out: F64 = c_sensor_mm + self._noise.normal(0.0, self.settings.sensor_noise_mm, 3)
        return out

    def sweep_job(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> SweepJob:
        """The sweep the sensor records of the sphere at p_part_mm from q_deg (to render): a
        move there (a new stop), the true centre from where the robot stands; raises
        NotVisible outside the measuring volume. Each call is a new sweep with its own noise
        seed (cell seed, sweep index), so results do not depend on where it is rendered."""
        c = self._visible_centre(q_deg, p_part_mm)
        with self._render_lock:
            k = self._sweeps
            self._sweeps += 1
        return SweepJob(
            c, self.spec.sphere_radius_mm, self.sweep_commands_v.copy(), (self.settings.seed, 3, k)
        )

    def render_sweep(
        self, q_deg: ArrayLike, p_part_mm: ArrayLike, *, stripe_truth: bool = False
    ) -> tuple[Frames, F64, SweepTruth]:
        """Render the sweep of the sphere at p_part_mm from q_deg: frames shape=(n, H, W)
        uint8, mirror commands shape=(n,) [V], the renderer's truth (true centre in S, planes).
        Raises NotVisible outside the measuring volume."""
        return self.sweep_job(q_deg, p_part_mm).render(self.sensor, stripe_truth=stripe_truth)

    # -- the robot's repeatability --------------------------------------------------------
    def new_stop_deg(self, q_deg: ArrayLike) -> F64:
        """The error (6,) [controller deg] of a new stop of the robot at q_deg: the attained
        joints are q_deg plus it (module docstring: seeded by the cell's seed, the joints' key
        and the stops there before; zero when repeatability_mm is 0)."""
        if self.repeatability.rp_mm == 0.0:
            return np.zeros(6)
        key = _joints_key(np.asarray(q_deg, dtype=float).reshape(6))
        with self._stop_lock:
            n = self._stops_seen.get(key, 0)
            self._stops_seen[key] = n + 1
        draw = [self.noise_draw] if self.noise_draw else []
        rng = np.random.default_rng([self.settings.seed, 9, key, n, *draw])
        return self.repeatability.draw_deg(rng)[0]

    def attained_deg(self) -> F64:
        """Where the true robot stands now (6,) [controller deg] on the World path: the
        commanded joints plus the error of the stop there, drawn when first asked after the
        joints changed (a move; the frames of a sweep share it)."""
        q, error = self._stop_now()
        out: F64 = q + error
        return out

    def _stop_now(self) -> tuple[F64, F64]:
        """The commanded joints now and their stop's error [deg] (`attained_deg`)."""
        with self._lock:
            q, moved, self._moved = self._q_deg.copy(), self._moved, False
            if moved:
                self._stop_error_deg = self.new_stop_deg(q)
            return q, self._stop_error_deg.copy()

    def centres_from_stops(
        self, q_deg: ArrayLike, p_part_mm: ArrayLike, t_s: float | None = None
    ) -> F64:
        """True centres (n, 3) in S of spheres at p_part_mm (n, 3), each seen from a stop of its
        own at q_deg (n, 6) at sim time t_s (default: now): measurements that are each a move,
        as the truth's validation positions are. The stops are seeded by the cell's seed and
        the time (to 1 ms): the same time, the same stops, whatever was asked before."""
        t = self._at(t_s)
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        rng = np.random.default_rng([self.settings.seed, 10, round(abs(t) * 1000.0)])
        stops = q + self.repeatability.draw_deg(rng, len(q))
        return self.centre_in_sensor(stops, p_part_mm, t - self._world_s)

    def track_point(self, p_part_mm: ArrayLike) -> F64:
        """Laser-tracker measurement (3,) [mm] of a point in the part frame."""
        p = np.asarray(p_part_mm, dtype=float)
        out: F64 = p + self._noise.normal(0.0, self.settings.tracker_noise_mm, 3)
        return out

    # -- the World protocol of the device fakes --------------------------------------------
    def set_joints_deg(self, q_deg: ArrayLike) -> None:
        q = np.asarray(q_deg, dtype=float).reshape(6).copy()
        with self._lock:
            self._moved = self._moved or not np.array_equal(q, self._q_deg)
            self._q_deg = q

    def joints_deg(self) -> F64:
        with self._lock:
            return self._q_deg.copy()

    def target_ids(self) -> list[str]:
        return sorted(self._spheres)

    def target_true_mm(self, target_id: str) -> F64:
        """Where the sphere stands now in the part frame (after a fixture's renewal, its
        new place)."""
        return self._sphere_now(target_id).copy()

    def _sphere_now(self, target_id: str) -> F64:
        t = self._at(None)
        if target_id in self._spheres_serviced and self._serviced(t):
            return self._spheres_serviced[target_id]
        moved = self._sphere_knocked
        if moved is not None and moved[0] == target_id and self._knocked(t):
            return self._spheres[target_id] + moved[1]
        return self._spheres[target_id]

    def place_sphere(self, target_id: str, p_part_mm: ArrayLike) -> None:
        """Put a sphere (a new one, or move one) at p_part_mm: the validation sphere on its
        tracker nest, which the camera and the tracker then see like the fixed ones."""
        with self._lock:
            self._spheres = {**self._spheres, target_id: np.array(p_part_mm, dtype=float)}

    def remove_sphere(self, target_id: str) -> None:
        with self._lock:
            self._spheres = {k: v for k, v in self._spheres.items() if k != target_id}

    def measure_target(self, target_id: str) -> F64:
        """Geometric sensor measurement of a named sphere from where the robot stands now
        (`attained_deg`: the stop at the current joints, the same for every call until the
        next move)."""
        q, error = self._stop_now()
        return self._sensed(self._visible_centre(q, self._sphere_now(target_id), error))

    def render_frame(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_v: float | None
    ) -> F64:
        """The frame the camera sees now (World protocol): the nearest sphere in front of the
        sensor at the current joints, lit by the laser plane of the galvo command.

        galvo_v: the galvo command [V] (None: no galvo, command 0 V); the true mirror angle
        follows the true sensor's own command-to-angle curve (fakes/render_sensor.py). Exposure
        scales the laser and the ambient light (linear in exposure, reference 10 ms); gain
        multiplies the digital numbers. Rendered in 12 bits and returned as float64 in [0, 1],
        shape (height, width): the top-left part of the 1296 x 966 sensor when smaller (the
        region's offset is not passed).
        """
        command_v = 0.0 if galvo_v is None else float(galvo_v)
        return self.render_frame_v(width, height, exposure_us, gain_db, command_v)

    def render_frame_v(
        self, width: int, height: int, exposure_us: float, gain_db: float, command_v: float
    ) -> F64:
        """As `render_frame`, for a mirror command in volts (the DAC's output): the true
        mirror angle follows the true sensor's command-to-angle polynomial."""
        counts, full_scale = self.render_counts_v(width, height, exposure_us, gain_db, command_v)
        out: F64 = counts.astype(np.float64) / float(full_scale)
        return out

    def render_counts(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_v: float | None
    ) -> tuple[NDArray[np.uint16], int]:
        """`render_frame`'s frame as the renderer's 12-bit digital numbers and their full scale
        (4095): the frame is these divided by it (fakes/world.py, `frame_in_format`)."""
        command_v = 0.0 if galvo_v is None else float(galvo_v)
        return self.render_counts_v(width, height, exposure_us, gain_db, command_v)

    def render_counts_v(
        self, width: int, height: int, exposure_us: float, gain_db: float, command_v: float
    ) -> tuple[NDArray[np.uint16], int]:
        """As `render_counts`, for a mirror command in volts (fakes/cell_camera.py)."""
        return self.frames.counts_v(width, height, exposure_us, gain_db, command_v)

    def warm_up(self) -> None:
        """The camera's first rendering paid now (`CameraFrames.warm_up`)."""
        self.frames.warm_up()

    def sphere_in_view(self) -> F64 | None:
        """True centre in the sensor frame [mm] of the nearest sphere wholly in front of the
        sensor (the spheres stand metres apart: at most one is ever in the field of view)."""
        q = self.attained_deg()
        spheres = self._spheres  # replaced whole when a sphere is placed: one snapshot
        if not spheres:
            return None
        pts = np.array(list(spheres.values()))
        T = self.T_part_sensor(q[None, :])[0]
        c = (pts - T[:3, 3]) @ T[:3, :3]
        front = c[:, 2] > self.spec.sphere_radius_mm
        if not np.any(front):
            return None
        dist = np.where(front, np.linalg.norm(c, axis=1), np.inf)
        out: F64 = c[int(np.argmin(dist))]
        return out


def _joints_key(q_deg: F64) -> int:
    """A stop's key: its controller joints to 0.1 deg (the frames' grid: fakes/cell_camera.py)."""
    return digest(np.round(q_deg * 10.0).astype(np.int64))
