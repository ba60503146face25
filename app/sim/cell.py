"""Wiring of the simulated cell: builds it from the cell configuration and collects
calibration and validation sets the way the line would (plan a view with the model, move the
true robot, measure with the sensor, measure the spheres with the tracker).

How a sphere centre is measured is a strategy passed to `collect`:

- `GeometricMeasurement`: the cell's true centre in the sensor frame plus Gaussian noise (fast);
- `RenderedMeasurement`: the cell renders the galvo sweep its true sensor records from the true
  pose (fakes.render), and vision.measure turns the frames into a centre with the sensor model,
  in this process or in a pool of worker processes. A sweep that the vision quality checks
  reject is skipped and counted (`DataSet.rejected`), never used.

Either way each view is a move of the true robot, which stands off by its repeatability
(fakes.cell); a DataSet's `truth_c_sensor_mm` is the centre from the commanded pose (what a
perfect sensor on a perfectly repeating robot measures), so the robot's stop error counts as
measurement noise, as it does on the line.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Protocol, Self

import cv2
import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.errors import InputError
from app.threads import exit_with_parent, forkserver_context
from app.workspace import workspace_points
from calib import candidates
from calib.identify import Measurements
from calib.model import SystemModel
from calib.validation import rmse
from fakes.cell import SimulatedCell, SweepJob
from fakes.cell_spec import CellSpec, MeasuringVolume, SimSettings
from fakes.render_sensor import TrueSensor
from fakes.render_targets import render_calibration_set
from vision.calibrate_sensor import calibrate_sensor
from vision.errors import VisionError
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import CameraModel, LaserModel, SensorModel, default_sensor_model

F64 = NDArray[np.float64]


def make_cell(
    cfg: CellConfig,
    seed: int | None = None,
    *,
    sensor: TrueSensor | None = None,
    **overrides: object,
) -> SimulatedCell:
    """The simulated cell of a configuration; `overrides` replace SimSettings fields; sensor:
    the true sensor (default: built on first use, its pixel rays take ~1 s)."""
    s = cfg.sensor
    volume = MeasuringVolume(
        half_x_mm=s["half_fov_x_mm"],
        half_y_mm=s["half_fov_y_mm"],
        z_min_mm=s["standoff_mm"] - s["half_depth_mm"],
        z_max_mm=s["standoff_mm"] + s["half_depth_mm"],
    )
    spec = CellSpec(
        cfg.T_part_base, cfg.T_flange_sensor, cfg.spheres_part_mm, s["sphere_radius_mm"], volume
    )
    sim = cfg.simulation
    settings = SimSettings(
        seed=int(sim["seed"] if seed is None else seed),
        tracker_noise_mm=float(sim["tracker_noise_mm"]),
        sensor_noise_mm=float(sim["sensor_noise_mm"]),
        repeatability_mm=float(sim["repeatability_mm"]),
        compliance=bool(sim["compliance"]),
        thermal=bool(sim["thermal"]),
        temp_c=float(sim["temp_c"]),
    )
    return SimulatedCell(spec, replace(settings, **overrides), sensor)  # type: ignore[arg-type]


@dataclass(frozen=True)
class SimulatedSets:
    """The simulated cell of a seed with its pre-calibration set (random configurations at the
    configured spheres) and its validation set; `rng` continues the seed's random stream."""

    cell: SimulatedCell
    model: SystemModel
    rng: np.random.Generator
    calibration: DataSet
    validation: DataSet


def simulated_sets(
    cfg: CellConfig,
    seed: int,
    *,
    n_each: int | None = None,
    n_validation: int = 100,
    measurement: Measurement | None = None,
    **overrides: object,
) -> SimulatedSets:
    """The one set-up of the simulated cell shared by demo, experiment, simulate and the tests:
    n_each (default: [calibration] configs_per_sphere) random views of every sphere, then
    n_validation validation positions, measured with `measurement` (default geometric)."""
    cell = make_cell(cfg, seed=seed, **overrides)  # type: ignore[arg-type]
    model = cfg.model()
    x0 = model.nominal_x()
    rng = np.random.default_rng([seed, 2])
    n = cfg.calibration.configs_per_sphere if n_each is None else n_each
    cal = collect(cell, model, x0, cfg.spheres_part_mm, n, rng, measurement=measurement)
    val = validation_set(cell, cfg, model, x0, n_validation, rng, measurement)
    return SimulatedSets(cell, model, rng, cal, val)


@dataclass(frozen=True)
class Rejection:
    """A view whose sweep the vision quality checks rejected: which target, from where, why."""

    target: str
    q_deg: F64
    reason: str


@dataclass(frozen=True)
class DataSet:
    """Measurements plus the tracker's target centres (part frame) they refer to; `rejected`
    lists the views whose measurement was rejected (and replaced by another view if any)."""

    measurements: Measurements
    targets: dict[str, F64]
    truth_c_sensor_mm: F64
    truth_p_part_mm: F64
    rejected: tuple[Rejection, ...] = ()


@dataclass(frozen=True)
class Outcome:
    """One measurement attempt: the centre in the sensor frame [mm], or None and the reason the
    quality checks gave; the seconds spent rendering and measuring (rendered path)."""

    c_sensor_mm: F64 | None
    reason: str = ""
    render_s: float = 0.0
    measure_s: float = 0.0


class Measurement(Protocol):
    """A way to measure sphere centres in the simulated cell (see the module docstring)."""

    name: str

    def measure(self, cell: SimulatedCell, views: Sequence[tuple[F64, F64]]) -> list[Outcome]:
        """Outcomes of measuring the spheres at p_part_mm from q_deg, for each (q_deg,
        p_part_mm) in order; every view must be inside the measuring volume (`cell.sees`)."""
        ...


class GeometricMeasurement:
    """The true centre in the sensor frame plus the cell's Gaussian sensor noise."""

    name = "geometric"

    def measure(self, cell: SimulatedCell, views: Sequence[tuple[F64, F64]]) -> list[Outcome]:
        return [Outcome(cell.measure_point(q, p)) for q, p in views]


def render_and_measure(
    job: SweepJob, sensor: TrueSensor, sensor_model: SensorModel, mode: str = "fast"
) -> Outcome:
    """Render one sweep with the true sensor and measure it with the sensor model."""
    t0 = time.perf_counter()
    frames, commands_v, _ = job.render(sensor)
    t1 = time.perf_counter()
    try:
        m = measure_sphere_from_sweep(frames, commands_v, sensor_model, mode=mode)
    except VisionError as exc:
        return Outcome(None, f"{type(exc).__name__}: {exc}", t1 - t0, time.perf_counter() - t1)
    return Outcome(m.c_sensor_mm, "", t1 - t0, time.perf_counter() - t1)


_WORKER: dict[str, object] = {}


def _init_worker(sensor: TrueSensor, sensor_model: SensorModel, mode: str) -> None:
    exit_with_parent()
    cv2.setNumThreads(1)
    _ = sensor.pixel_rays
    _WORKER.update(sensor=sensor, model=sensor_model, mode=mode)


def _worker_task(job: SweepJob) -> Outcome:
    sensor, model, mode = _WORKER["sensor"], _WORKER["model"], _WORKER["mode"]
    assert isinstance(sensor, TrueSensor) and isinstance(model, SensorModel)
    return render_and_measure(job, sensor, model, str(mode))


@dataclass
class RenderedMeasurement:
    """Sphere centres through rendered images: the cell renders each sweep, vision measures it.

    sensor_model: the calibration the line would load (default: the simulated sensor's design);
    workers: processes rendering and measuring in parallel (1: in this process; the pool starts
    on first use, each worker builds the sensor's pixel rays once); mode: stripe extraction
    mode; progress: called with a one-line status every `every` sweeps and after each batch.
    Counters (sweeps, rejected, seconds) accumulate over every call; use as a context manager
    or call close() to stop the workers.
    """

    sensor_model: SensorModel = field(default_factory=default_sensor_model)
    #: False when sensor_model is an estimate (its frame is not exactly the true sensor's)
    sensor_frame_exact: bool = True
    workers: int = 1
    mode: str = "fast"
    progress: Callable[[str], None] | None = None
    every: int = 10
    name: str = "rendered"
    sweeps: int = 0
    rejected: int = 0
    render_s: float = 0.0
    measure_s: float = 0.0
    wall_s: float = 0.0
    frames_per_sweep: int = 0
    _pool: Executor | None = field(default=None, repr=False)
    _pool_sensor: TrueSensor | None = field(default=None, repr=False)

    def measure(self, cell: SimulatedCell, views: Sequence[tuple[F64, F64]]) -> list[Outcome]:
        t0 = time.perf_counter()
        jobs = [cell.sweep_job(q, p) for q, p in views]
        if jobs:
            self.frames_per_sweep = len(jobs[0].commands_v)
        out = []
        for outcome in self._run(cell, jobs):
            out.append(outcome)
            self.sweeps += 1
            self.rejected += outcome.c_sensor_mm is None
            self.render_s += outcome.render_s
            self.measure_s += outcome.measure_s
            if self.progress is not None and self.sweeps % self.every == 0:
                self.progress(self.status(self.wall_s + time.perf_counter() - t0))
        self.wall_s += time.perf_counter() - t0
        if self.progress is not None and self.sweeps % self.every != 0 and jobs:
            self.progress(self.status(self.wall_s))
        return out

    def status(self, wall_s: float) -> str:
        return (
            f"  rendered and measured {self.sweeps} sweeps ({self.rejected} rejected) in "
            f"{wall_s:.1f} s"
        )

    def _run(self, cell: SimulatedCell, jobs: list[SweepJob]) -> Iterator[Outcome]:
        if self.workers <= 1 or len(jobs) <= 1:
            sensor = cell.sensor
            return (render_and_measure(j, sensor, self.sensor_model, self.mode) for j in jobs)
        if self._pool is None or self._pool_sensor is not cell.sensor:
            self.close()
            self._pool_sensor = cell.sensor
            self._pool = ProcessPoolExecutor(
                self.workers,
                mp_context=forkserver_context(__name__),
                initializer=_init_worker,
                initargs=(replace(cell.sensor), self.sensor_model, self.mode),
            )  # no ray cache
        return self._pool.map(_worker_task, jobs)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def collect(
    cell: SimulatedCell,
    model: SystemModel,
    x: F64,
    points_part_mm: Mapping[str, F64],
    n_each: int,
    rng: np.random.Generator,
    q_by_target: Mapping[str, F64] | None = None,
    measurement: Measurement | None = None,
    max_total: int | None = None,
) -> DataSet:
    """Measure each point from n_each views that see it, random ones (3 n_each drawn per point)
    or the given configurations, in order; stop at max_total measurements overall.

    measurement: the strategy (default geometric). Views are measured in batches (every point's
    next views at once, so a rendering strategy can work in parallel); a rejected view is
    recorded and the point's next view is tried. Rows come out point by point, in the order
    of the points and of their views.
    """
    measurement = measurement or GeometricMeasurement()
    targets = {tid: cell.track_point(p) for tid, p in points_part_mm.items()}
    queue: dict[str, list[F64]] = {}
    for tid, p in points_part_mm.items():
        if q_by_target is not None:
            options = np.asarray(q_by_target[tid]).reshape(-1, 6)
        else:
            options = candidates.random_configurations(model, x, p, 3 * n_each, rng).q_deg
        queue[tid] = list(options[cell.sees_each(options, p)])
    got: dict[str, list[tuple[F64, F64]]] = {tid: [] for tid in points_part_mm}
    rejected: list[Rejection] = []
    budget = np.inf if max_total is None else max_total
    while True:
        batch: list[tuple[str, F64]] = []
        room = budget - sum(len(v) for v in got.values())
        for tid in points_part_mm:
            k = min(n_each - len(got[tid]), len(queue[tid]), int(min(room - len(batch), n_each)))
            batch += [(tid, queue[tid].pop(0)) for _ in range(max(k, 0))]
        if not batch:
            break
        views = [(q, points_part_mm[tid]) for tid, q in batch]
        for (tid, q), outcome in zip(batch, measurement.measure(cell, views), strict=True):
            if outcome.c_sensor_mm is None:
                rejected.append(Rejection(tid, q, outcome.reason))
            else:
                got[tid].append((q, outcome.c_sensor_mm))
    qs, cs, ps, ids, c_true, p_true = [], [], [], [], [], []
    for tid, p in points_part_mm.items():
        for q, c in got[tid]:
            qs.append(q)
            cs.append(c)
            ps.append(targets[tid])
            ids.append(tid)
            c_true.append(cell.centre_in_sensor(q, p)[0])
            p_true.append(p)
    meas = Measurements(
        np.array(qs).reshape(-1, 6),
        np.array(cs).reshape(-1, 3),
        np.array(ps).reshape(-1, 3),
        tuple(ids),
    )
    return DataSet(
        meas,
        targets,
        np.array(c_true).reshape(-1, 3),
        np.array(p_true).reshape(-1, 3),
        tuple(rejected),
    )


def check_complete(
    ds: DataSet, wanted: Mapping[str, int], source: str, total: int | None = None
) -> None:
    """InputError unless every target has its wanted number of measurements (and the set
    `total` rows), all finite: a sphere that no view reaches is named, never left out."""
    m = ds.measurements
    counts = {t: m.targets.count(t) for t in wanted}
    short = [f"{t} ({counts[t]} of {n})" for t, n in wanted.items() if counts[t] < n]
    if total is not None and len(m) < total:
        raise InputError(
            f"only {len(m)} of {total} validation positions could be measured", file=source
        )
    if short and total is None:
        raise InputError(
            "[spheres] positions_mm: too few views reach sphere " + ", ".join(short), file=source
        )
    if not all(np.all(np.isfinite(a)) for a in (m.q_deg, m.c_sensor_mm, m.p_part_mm)):
        raise InputError("the simulation produced non-finite values", file=source)


def validation_set(
    cell: SimulatedCell,
    cfg: CellConfig,
    model: SystemModel,
    x: F64,
    n: int,
    rng: np.random.Generator,
    measurement: Measurement | None = None,
) -> DataSet:
    """n validation positions each measured from one random configuration that sees it
    (positions that no view sees, or whose views are all rejected, are replaced)."""
    sets: list[DataSet] = []
    have = 0
    for _ in range(20):
        if have >= n:
            break
        points = workspace_points(cfg, 2 * (n - have), rng)
        points = {f"V{have + k + 1:03d}": p for k, p in enumerate(points.values())}
        ds = collect(cell, model, x, points, 1, rng, measurement=measurement, max_total=n - have)
        keep = [i for i in range(len(ds.measurements))][: n - have]
        sets.append(_take(ds, keep, have))
        have += len(keep)
    return _concat(sets)


def _take(ds: DataSet, rows: list[int], start: int) -> DataSet:
    m = ds.measurements.subset(np.array(rows, dtype=int))
    rename = {old: f"V{start + k + 1:03d}" for k, old in enumerate(m.targets)}
    meas = Measurements(m.q_deg, m.c_sensor_mm, m.p_part_mm, tuple(rename[t] for t in m.targets))
    targets = {rename[t]: ds.targets[t] for t in m.targets}
    rejected = tuple(
        replace(r, target=rename.get(r.target, f"{r.target} (position dropped)"))
        for r in ds.rejected
    )
    return DataSet(meas, targets, ds.truth_c_sensor_mm[rows], ds.truth_p_part_mm[rows], rejected)


def _concat(sets: list[DataSet]) -> DataSet:
    meas = Measurements(
        np.concatenate([s.measurements.q_deg for s in sets]),
        np.concatenate([s.measurements.c_sensor_mm for s in sets]),
        np.concatenate([s.measurements.p_part_mm for s in sets]),
        tuple(t for s in sets for t in s.measurements.targets),
    )
    targets = {k: v for s in sets for k, v in s.targets.items()}
    return DataSet(
        meas,
        targets,
        np.concatenate([s.truth_c_sensor_mm for s in sets]),
        np.concatenate([s.truth_p_part_mm for s in sets]),
        tuple(r for s in sets for r in s.rejected),
    )


def measurement_report(measurement: Measurement, sets: Mapping[str, DataSet]) -> dict[str, object]:
    """What the demo reports about its measurements: the path, the centre error against the
    cell's truth (the centre from the commanded pose: the robot's repeatability and the sensor's
    error; RMS of the 3D distance and per axis, um) and the rejected views per data set,
    and for the rendered path the sweeps and their times (per sweep: render, measure in the
    worker; wall time of all sweeps)."""
    out: dict[str, object] = {"path": measurement.name}
    for name, ds in sets.items():
        e_um = 1000.0 * (ds.measurements.c_sensor_mm - ds.truth_c_sensor_mm)
        out[name] = {
            "n": len(ds.measurements),
            "centre_error_rms_um": rmse(e_um),
            "centre_error_rms_xyz_um": np.sqrt(np.mean(e_um**2, axis=0)).tolist(),
            "rejected": len(ds.rejected),
            "rejections": [f"{r.target}: {r.reason}" for r in ds.rejected],
        }
    if isinstance(measurement, RenderedMeasurement) and measurement.sweeps:
        n = measurement.sweeps
        out["rendered"] = {
            "sweeps": n,
            "rejected": measurement.rejected,
            "frames_per_sweep": measurement.frames_per_sweep,
            "workers": measurement.workers,
            "render_ms_per_sweep": 1000.0 * measurement.render_s / n,
            "measure_ms_per_sweep": 1000.0 * measurement.measure_s / n,
            "wall_s": measurement.wall_s,
        }
    return out


def true_sensor_model(true: TrueSensor) -> SensorModel:
    """The simulated sensor's truth as a vision SensorModel (a perfect calibration), for tests,
    benchmarks and the demo. Exact when the mirror offset is zero; otherwise the laser plane
    at angle 0 serves as the reference."""
    K = np.array([[true.fx_px, 0, true.cx_px], [0, true.fy_px, true.cy_px], [0, 0, 1.0]])
    u = true.axis_dir / np.linalg.norm(true.axis_dir)
    n_ref, _ = true.laser_planes(np.array([0.0]))
    n0 = n_ref[0] - u * (u @ n_ref[0])
    n0 = n0 / np.linalg.norm(n0)
    if n0[0] < 0:
        n0 = -n0
    laser = LaserModel(
        axis_point_mm=true.axis_point_mm.copy(),
        axis_dir=u,
        ref_normal=n0,
        angle_poly_rad=true.angle_poly_rad.copy(),
    )
    camera = CameraModel(
        K=K, dist=true.dist.copy(), width_px=true.width_px, height_px=true.height_px
    )
    return SensorModel(camera=camera, laser=laser, name="simulated truth")


def scaled_sensor_model(
    model: SensorModel, focal_scale: float, cx_shift_px: float = 0.0
) -> SensorModel:
    """`model` with its focal lengths scaled and its principal point moved by cx_shift_px: a
    sensor calibration with a known error (0.1 % in scale: focal_scale 1.001)."""
    K = model.camera.K.copy()
    K[0, 0] *= focal_scale
    K[1, 1] *= focal_scale
    K[0, 2] += cx_shift_px
    return replace(model, camera=replace(model.camera, K=K))


def calibrated_sensor_model(true: TrueSensor, seed: int) -> tuple[SensorModel, dict[str, float]]:
    """The sensor calibrated the way the line would (vision.calibrate_sensor from 12 rendered
    chessboards and 4 flat-target sweeps of 9 commands), and how far it is from the truth:
    focal length and principal point errors [px], reprojection RMS [px]."""
    cs = render_calibration_set(
        true, np.random.default_rng([seed, 11]), n_chessboards=12, n_targets=4, n_commands=9
    )
    targets = [(board, list(frames)) for board, frames in cs.targets]
    model = calibrate_sensor(cs.chessboards, targets, cs.commands_v)
    K = model.camera.K
    info = {
        "fx_error_px": float(K[0, 0] - true.fx_px),
        "fy_error_px": float(K[1, 1] - true.fy_px),
        "cx_error_px": float(K[0, 2] - true.cx_px),
        "cy_error_px": float(K[1, 2] - true.cy_px),
        "reprojection_rms_px": float(model.camera.rms_reprojection_px or float("nan")),
    }
    return model, info
