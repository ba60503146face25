"""The sensor across its measuring volume (issue 27, part 4): rejected views and centre error of
the sensor model calibrated as commissioning does it, against the true model.

    PYTHONPATH=. .venv/bin/python bench/sensor_volume.py [--seeds 0 1 2 3 4] [--grid 5 5 3]
        [--models calibrated true] [--cell CELL.toml] [--map]

Per seed: the targets the engineer records in `rvis commission --sim` (app/sim/commission.py
`SimCommissioning.capture`: `[commission] chessboards` and `flat_targets`, 9 sweep commands,
rendered by the cell's true sensor from the rng [seed, 11]) calibrated with
vision.calibrate_sensor; then one sphere sweep (the cell's commands, its radius) per sphere
centre on a grid spanning the whole measuring volume (the `[sensor]` field of view x the depth,
edges included, as `MeasuringVolume.contains` accepts them), rendered by the true sensor and
measured with each model. Models (--models):

- `calibrated`: the commissioning's calibration; `true`: the renderer's truth (a perfect one);
- `true-camera`: the true intrinsics, the laser calibrated from the same target data with them;
- `true-laser`: the calibrated intrinsics with the true laser.

Printed per seed and model: views rejected by the vision quality checks; then, of every view
(measured again with the checks off, so that the rejected views count too), the centre error
against the truth (RMS, max, and its spread about its mean: what a hand-eye cannot absorb),
the free-radius deviation (mean, max |dev|) and the free/certified centre shift (max); then
each rejected view's place (x, y, z [mm]) and reason; with --map the centre error per grid
point, by depth.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.threads import limit_blas_threads

limit_blas_threads()

import cv2
import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig, load_cell
from app.sim.cell import true_sensor_model
from fakes.cell import SWEEP_FRAMES, SWEEP_SPAN_V
from fakes.render import default_sweep_commands, render_sphere_sweep
from fakes.render_sensor import TrueSensor, default_true_sensor
from fakes.render_targets import CalibrationSet, render_calibration_set
from vision.calibrate import calibrate_laser, laser_points, target_plane
from vision.calibrate_sensor import calibrate_sensor
from vision.errors import SphereFitRejected, VisionError
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import CameraModel, SensorModel
from vision.spherefit import FitThresholds

F64 = NDArray[np.float64]
MODELS = ("calibrated", "true", "true-camera", "true-laser")
#: the checks off: every view gets a centre and its quality figures
NO_CHECKS = FitThresholds(
    min_points=10,
    min_inlier_fraction=0.0,
    max_rms_mm=1e9,
    min_coverage_deg=0.0,
    max_radius_dev_mm=1e9,
    max_centre_shift_mm=1e9,
)
COMMANDS_PER_TARGET = 9  # app/commission/capture.py SWEEP_COMMANDS


def calibration_set(cfg: CellConfig, sensor: TrueSensor, seed: int) -> CalibrationSet:
    """What `SimCommissioning.capture` records for this seed."""
    c = cfg.commission
    return render_calibration_set(
        sensor,
        np.random.default_rng([seed, 11]),
        n_chessboards=c.chessboards,
        n_targets=c.flat_targets,
        n_commands=COMMANDS_PER_TARGET,
    )


def _laser_with(camera: CameraModel, cs: CalibrationSet) -> SensorModel:
    pts = [
        laser_points(frames, target_plane(board, camera), camera) for board, frames in cs.targets
    ]
    return SensorModel(camera=camera, laser=calibrate_laser(pts, cs.commands_v))


def models_for(names: list[str], cs: CalibrationSet, sensor: TrueSensor) -> dict[str, SensorModel]:
    truth = true_sensor_model(sensor)
    targets = [(board, list(frames)) for board, frames in cs.targets]
    calibrated = calibrate_sensor(cs.chessboards, targets, cs.commands_v)
    out: dict[str, SensorModel] = {}
    for name in names:
        if name == "calibrated":
            out[name] = calibrated
        elif name == "true":
            out[name] = truth
        elif name == "true-camera":
            out[name] = _laser_with(truth.camera, cs)
        elif name == "true-laser":
            out[name] = SensorModel(camera=calibrated.camera, laser=truth.laser)
    return out


def grid(cfg: CellConfig, n: tuple[int, int, int]) -> F64:
    """Sphere centres [mm] in the sensor frame spanning the measuring volume, edges included."""
    s = cfg.sensor
    xs = np.linspace(-s["half_fov_x_mm"], s["half_fov_x_mm"], n[0])
    ys = np.linspace(-s["half_fov_y_mm"], s["half_fov_y_mm"], n[1])
    zs = np.linspace(
        s["standoff_mm"] - s["half_depth_mm"], s["standoff_mm"] + s["half_depth_mm"], n[2]
    )
    return np.array([[x, y, z] for z in zs for y in ys for x in xs])


@dataclass
class View:
    """One view measured with one model: the error [mm] with the checks off (None when even
    that fails), the quality, and the reason of the real checks ("" when accepted)."""

    error_mm: F64 | None
    radius_dev_mm: float
    centre_shift_mm: float
    reason: str


def measure(frames: NDArray[np.generic], cmds: F64, model: SensorModel, c: F64) -> View:
    try:
        loose = measure_sphere_from_sweep(frames, cmds, model, thresholds=NO_CHECKS)
    except VisionError as exc:
        return View(None, np.nan, np.nan, f"{type(exc).__name__}: {exc}")
    q = loose.quality
    reason = ""
    try:
        measure_sphere_from_sweep(frames, cmds, model)
    except SphereFitRejected as exc:
        reason = str(exc)
    except VisionError as exc:
        reason = f"{type(exc).__name__}: {exc}"
    return View(loose.c_sensor_mm - c, q.radius_dev_mm, q.centre_shift_mm, reason)


def summary(per_seed: list[list[View]]) -> dict[str, float]:
    """The figures of the views of one or more seeds (the spread about each seed's mean)."""
    views = [v for seed in per_seed for v in seed]
    errors = [[v.error_mm for v in seed if v.error_mm is not None] for seed in per_seed]
    e = np.array([x for seed in errors for x in seed]).reshape(-1, 3) * 1000.0
    about = [np.array(seed) - np.mean(seed, axis=0) for seed in errors if seed]
    spread = np.linalg.norm(np.concatenate(about), axis=1) * 1000.0 if about else np.zeros(1)
    dev = np.array([v.radius_dev_mm for v in views]) * 1000.0
    shift = np.array([v.centre_shift_mm for v in views]) * 1000.0
    norm = np.linalg.norm(e, axis=1) if len(e) else np.zeros(1)
    return {
        "rejected": sum(1 for v in views if v.reason) / len(views),
        "n_rejected": sum(1 for v in views if v.reason),
        "rms_um": float(np.sqrt(np.mean(norm**2))),
        "max_um": float(norm.max()),
        "spread_rms_um": float(np.sqrt(np.mean(spread**2))),
        "spread_max_um": float(spread.max()),
        "dev_mean_um": float(np.nanmean(dev)),
        "dev_max_um": float(np.nanmax(np.abs(dev))),
        "shift_max_um": float(np.nanmax(shift)),
    }


HEADER = (
    f"{'seed':>4} {'model':<12} {'rejected':>12} {'err RMS':>8} {'err max':>8} "
    f"{'spread RMS':>10} {'spread max':>10} {'dev mean':>8} {'|dev| max':>9} {'shift max':>9}"
)


def row(seed: int | str, name: str, n: int, s: dict[str, float]) -> str:
    return (
        f"{seed!s:>4} {name:<12} {int(s['n_rejected']):>3}/{n:<3} {100 * s['rejected']:4.1f}%"
        f" {s['rms_um']:8.1f} {s['max_um']:8.1f} {s['spread_rms_um']:10.1f} "
        f"{s['spread_max_um']:10.1f} {s['dev_mean_um']:+8.1f} {s['dev_max_um']:9.1f} "
        f"{s['shift_max_um']:9.1f}"
    )


def error_map(centres: F64, views: list[View]) -> None:
    """|centre error| [um] per grid point, one block per depth; `*` marks a rejected view."""
    for z in np.unique(centres[:, 2]):
        at = np.flatnonzero(centres[:, 2] == z)
        xs, ys = np.unique(centres[at, 0]), np.unique(centres[at, 1])
        print(f"      z = {z:.1f} mm   x: " + " ".join(f"{x:7.1f}" for x in xs))
        for y in ys:
            cells = []
            for x in xs:
                i = at[(centres[at, 0] == x) & (centres[at, 1] == y)][0]
                v = views[i]
                mag = np.nan if v.error_mm is None else 1000 * float(np.linalg.norm(v.error_mm))
                cells.append(f"{mag:6.0f}{'*' if v.reason else ' '}")
            print(f"      y = {y:6.1f}          " + " ".join(cells))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--grid", type=int, nargs=3, default=[5, 5, 3], metavar=("NX", "NY", "NZ"))
    p.add_argument("--models", nargs="+", choices=MODELS, default=["calibrated", "true"])
    p.add_argument("--cell", default=None, help="cell file (default: the embedded cell)")
    p.add_argument("--map", action="store_true", help="print the error map of each model")
    args = p.parse_args(argv)
    cv2.setNumThreads(1)
    cfg = load_cell(args.cell)
    sensor = default_true_sensor()
    centres = grid(cfg, tuple(args.grid))
    cmds = default_sweep_commands(SWEEP_FRAMES, SWEEP_SPAN_V)
    radius = float(cfg.sensor["sphere_radius_mm"])
    c = cfg.commission
    print(
        f"{len(centres)} sphere centres on a {'x'.join(map(str, args.grid))} grid over the "
        f"measuring volume; {c.chessboards} chessboards, {c.flat_targets} flat targets x "
        f"{COMMANDS_PER_TARGET} commands; sweeps of {len(cmds)} frames over +-{SWEEP_SPAN_V} V"
    )
    print("errors in um (3-D distance); spread: about the mean error; dev: free - certified radius")
    totals: dict[str, list[list[View]]] = {m: [] for m in args.models}
    lines = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        cs = calibration_set(cfg, sensor, seed)
        models = models_for(args.models, cs, sensor)
        K = models["calibrated"].camera.K if "calibrated" in models else None
        views: dict[str, list[View]] = {m: [] for m in args.models}
        for k, centre in enumerate(centres):
            frames, _, _ = render_sphere_sweep(
                centre,
                radius,
                sensor,
                np.random.default_rng([seed, 3, k]),
                commands_v=cmds,
                stripe_truth=False,
            )
            for name, model in models.items():
                views[name].append(measure(frames, cmds, model, centre))
        print(f"\n== seed {seed} ({time.perf_counter() - t0:.0f} s)", end="")
        if K is not None:
            print(
                f": calibrated fx {K[0, 0] - sensor.fx_px:+.2f} fy {K[1, 1] - sensor.fy_px:+.2f} "
                f"cx {K[0, 2] - sensor.cx_px:+.2f} cy {K[1, 2] - sensor.cy_px:+.2f} px, "
                f"dist {np.array2string(models['calibrated'].camera.dist, precision=4)}"
            )
        else:
            print()
        print(HEADER)
        for name in args.models:
            line = row(seed, name, len(centres), summary([views[name]]))
            print(line)
            lines.append(line)
            totals[name].append(views[name])
            for centre, v in zip(centres, views[name], strict=True):
                if v.reason:
                    print(
                        f"     {name} rejected at {np.array2string(centre, precision=1)}: "
                        f"{v.reason}"
                    )
            if args.map:
                print(f"   {name}: |centre error| um")
                error_map(centres, views[name])
    print("\n== all seeds")
    print(HEADER)
    for line in lines:
        print(line)
    for name in args.models:
        print(row("all", name, len(centres) * len(args.seeds), summary(totals[name])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
