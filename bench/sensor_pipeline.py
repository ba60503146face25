"""Benchmark of the sensor pipeline (not run by the tests): timings and accuracy vs the truth.

    .venv/bin/python bench/sensor_pipeline.py [--poses 50] [--frames 48] [--repeats 30]
                                              [--calib-seeds 3] [--cell-sweeps 16] [--workers 2]

Prints medians of repeated runs (one OpenCV thread): stripe extraction per 1296x966 frame in both
modes, triangulation + sphere fit per sweep, the renderer apart; then the centre error of 50
sphere poses over the field of view with a perfect sensor model, and the absolute error left
after calibrating the sensor from rendered chessboards and target sweeps, split into what the
intrinsics and what the laser calibration contribute. Last, the simulated cell measured through
rendered images as `rvis demo` does it (24-frame sweeps from random views of the four spheres):
render and measure time per sweep (wall and CPU) in this process, then the wall time per sweep
with a pool of worker processes.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point, before numpy loads

import cv2
import numpy as np
from numpy.typing import NDArray

from app.sim.cell import true_sensor_model
from fakes.render import default_sweep_commands, render_sphere_sweep
from fakes.render_sensor import TrueSensor, default_true_sensor
from fakes.render_targets import CalibrationSet, render_calibration_set
from vision.calibrate import calibrate_camera, calibrate_laser, laser_points, target_plane
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import CameraModel, SensorModel
from vision.spherefit import fit_sphere
from vision.stripe import extract_stripe, extract_sweep
from vision.triangulate import triangulate_sweep

F64 = NDArray[np.float64]


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1000.0 * float(np.median(times))


def bench_timings(sensor: TrueSensor, model: SensorModel, n_frames: int, repeats: int) -> None:
    rng = np.random.default_rng(1)
    cmds = default_sweep_commands(n_frames, 3.2)
    c = np.array([0.0, 0.0, 130.0])
    t = time.perf_counter()
    frames, _, _ = render_sphere_sweep(c, 15.0, sensor, rng, commands_v=cmds)
    render_s = time.perf_counter() - t
    mid = frames[n_frames // 2]
    print("== timings (median, 1 OpenCV thread)")
    fast_ms = median_ms(lambda: extract_stripe(mid), repeats)
    print(f"stripe fast     per 1296x966 frame : {fast_ms:7.2f} ms")
    sweep_ms = median_ms(lambda: extract_sweep(frames), max(repeats // 3, 5))
    print(
        f"stripe fast     per frame of a {n_frames}-frame sweep (extract_sweep): "
        f"{sweep_ms / n_frames:7.2f} ms"
    )
    print(
        f"stripe precise  per 1296x966 frame : "
        f"{median_ms(lambda: extract_stripe(mid, 'precise'), repeats):7.2f} ms"
    )
    for mode in ("fast", "precise"):
        stripes = [extract_stripe(f, mode) for f in frames]
        n_pts = sum(len(s) for s in stripes)

        def tri_fit(stripes: list = stripes) -> None:  # type: ignore[type-arg]
            X, _ = triangulate_sweep(stripes, cmds, model)
            fit_sphere(X, 15.0)

        print(
            f"triangulation + fit per sweep ({mode:7s}, {n_frames} frames, {n_pts} points): "
            f"{median_ms(tri_fit, max(repeats // 3, 5)):7.2f} ms"
        )
    whole = median_ms(lambda: measure_sphere_from_sweep(frames, cmds, model), 5)
    print(f"whole measurement per sweep (fast, extraction included)   : {whole:7.1f} ms")
    print(
        f"renderer (apart): {1000 * render_s / n_frames:.1f} ms per frame, "
        f"{render_s:.2f} s per {n_frames}-frame sweep"
    )


def poses(rng: np.random.Generator, n: int) -> F64:
    """Sphere centres spread over the measuring volume around (0, 0, 130) mm."""
    return np.array([0.0, 0.0, 130.0]) + rng.uniform([-4, -3, -4], [4, 3, 4], size=(n, 3))


def render_sweeps(sensor: TrueSensor, centres: F64, n_frames: int, seed: int) -> list:  # type: ignore[type-arg]
    rng = np.random.default_rng(seed)
    cmds = default_sweep_commands(n_frames, 3.2)
    return [render_sphere_sweep(c, 15.0, sensor, rng, commands_v=cmds)[:2] for c in centres]


def centre_errors(sweeps: list, centres: F64, model: SensorModel, mode: str = "fast") -> F64:  # type: ignore[type-arg]
    return (
        np.array([measure_sphere_from_sweep(f, c, model, mode=mode).c_sensor_mm for f, c in sweeps])
        - centres
    )


def rigid_residual(measured: F64, true: F64) -> F64:
    """Residuals after the best rigid transform measured -> true (what hand-eye absorbs)."""
    mm, mt = measured.mean(axis=0), true.mean(axis=0)
    U, _, Vt = np.linalg.svd((measured - mm).T @ (true - mt))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return np.asarray((measured - mm) @ R.T + mt - true)


def report(name: str, err_mm: F64) -> None:
    e = err_mm * 1000.0
    print(
        f"{name}: bias um {np.array2string(e.mean(0), precision=2)}  std um "
        f"{np.array2string(e.std(0), precision=2)}  max |e| um {np.abs(e).max():.1f}"
    )


def laser_with(camera: CameraModel, cset: CalibrationSet) -> SensorModel:
    pts = [
        laser_points(frames, target_plane(board, camera), camera) for board, frames in cset.targets
    ]
    return SensorModel(camera=camera, laser=calibrate_laser(pts, cset.commands_v))


def bench_calibration(sensor: TrueSensor, sweeps: list, centres: F64, seed: int) -> None:  # type: ignore[type-arg]
    rng = np.random.default_rng(seed)
    t = time.perf_counter()
    cset = render_calibration_set(sensor, rng)
    t_render = time.perf_counter() - t
    t = time.perf_counter()
    camera, _ = calibrate_camera(cset.chessboards)
    full = laser_with(camera, cset)
    t_cal = time.perf_counter() - t
    truth = true_sensor_model(sensor)
    laser_only = laser_with(truth.camera, cset)
    K = camera.K
    print(
        f"-- calibration seed {seed}: render {t_render:.1f} s, calibrate {t_cal:.2f} s; "
        f"fx {100 * (K[0, 0] / sensor.fx_px - 1):+.3f} %, fy "
        f"{100 * (K[1, 1] / sensor.fy_px - 1):+.3f} %, cx {K[0, 2] - sensor.cx_px:+.2f} px, "
        f"cy {K[1, 2] - sensor.cy_px:+.2f} px, reprojection {camera.rms_reprojection_px:.3f} "
        f"px, laser plane rms {full.laser.rms_plane_mm * 1000:.1f} um"
    )
    e_full = centre_errors(sweeps, centres, full)
    report("   calibrated sensor (absolute)          ", e_full)
    report("   same, after best rigid transform      ", rigid_residual(e_full + centres, centres))
    report("   true intrinsics, calibrated laser only", centre_errors(sweeps, centres, laser_only))


def bench_cell(n_sweeps: int, workers: int) -> None:
    from app.config import load_cell
    from app.sim.cell import RenderedMeasurement, make_cell, render_and_measure
    from calib import candidates

    cfg = load_cell(None)
    model = cfg.model()
    x = model.nominal_x()
    cell = make_cell(cfg, seed=0)
    rng = np.random.default_rng(0)
    views = [
        (q, p)
        for p in cfg.spheres_part_mm.values()
        for q in candidates.random_configurations(model, x, p, n_sweeps, rng).q_deg
        if cell.sees(q, p)
    ]
    views = [views[i] for i in np.linspace(0, len(views) - 1, n_sweeps).astype(int)]
    _ = cell.sensor.pixel_rays
    model_s = RenderedMeasurement().sensor_model
    render, measure, wall, cpu, err = [], [], [], [], []
    for q, p in views:
        job = cell.sweep_job(q, p)
        t, c = time.perf_counter(), time.process_time()
        o = render_and_measure(job, cell.sensor, model_s)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        render.append(o.render_s)
        measure.append(o.measure_s)
        if o.c_sensor_mm is not None:
            err.append(1000 * np.linalg.norm(o.c_sensor_mm - job.c_sensor_mm))
    print(
        f"== rendered cell measurement per sweep ({n_sweeps} sweeps of "
        f"{len(cell.sweep_commands_v)} frames, median)"
    )
    print(
        f"in process: render {1000 * np.median(render):.0f} ms + measure "
        f"{1000 * np.median(measure):.0f} ms = wall {1000 * np.median(wall):.0f} ms "
        f"(CPU {1000 * np.median(cpu):.0f} ms); centre error 3D RMS "
        f"{np.sqrt(np.mean(np.square(err))):.1f} um, {n_sweeps - len(err)} rejected"
    )
    if workers > 1:
        with RenderedMeasurement(workers=workers) as m:
            m.measure(cell, views[:workers])  # start the workers (pixel rays ~1 s each)
            t = time.perf_counter()
            m.measure(cell, views)
            per_sweep_ms = 1000 * (time.perf_counter() - t) / n_sweeps
            print(f"{workers} worker processes: wall {per_sweep_ms:.0f} ms per sweep")


def _at_least_one(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"needs at least 1, got {n}")
    return n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--poses", type=_at_least_one, default=50)
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--calib-seeds", type=int, default=3)
    parser.add_argument("--cell-sweeps", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--only-cell", action="store_true", help="only the cell measurement")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    if args.only_cell:
        if args.cell_sweeps > 0:
            bench_cell(args.cell_sweeps, args.workers)
        return
    sensor = default_true_sensor()
    model = true_sensor_model(sensor)
    bench_timings(sensor, model, args.frames, args.repeats)
    centres = poses(np.random.default_rng(50), args.poses)
    t = time.perf_counter()
    sweeps = render_sweeps(sensor, centres, args.frames, seed=51)
    print(
        f"== accuracy: {args.poses} sphere poses over the field of view, {args.frames} frames "
        f"per sweep, default noise + speckle (rendered in {time.perf_counter() - t:.0f} s)"
    )
    for mode in ("fast", "precise"):
        report(f"perfect sensor model, {mode:7s}", centre_errors(sweeps, centres, model, mode))
    print(
        "== sensor calibrated from rendered chessboards (12 views) and target sweeps "
        "(4 poses x 15 commands)"
    )
    for seed in range(args.calib_seeds):
        bench_calibration(sensor, sweeps, centres, seed=100 + seed)
    if args.cell_sweeps > 0:
        bench_cell(args.cell_sweeps, args.workers)


if __name__ == "__main__":
    main()
