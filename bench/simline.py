"""Benchmark of the simulated line through the real drivers: start and close, the RMI motion
time against the expected one at several clock scales, one frame through Aravis against a
direct render (same run), and one sphere measured through the drivers (galvo step + grab per
frame, vision on the frames) against the cell's truth. Prints medians of repeated runs.

    .venv/bin/python bench/simline.py
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import CellConfig, load_cell
from app.sim.cell import make_cell
from calib import candidates
from drivers import registry
from drivers.camera import CameraSettings
from drivers.galvo import Galvo
from fakes.cell import SimulatedCell
from fakes.line import SimLine, SimLineSetup
from fakes.render import sphere_scene
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import default_sensor_model

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
FULL = CameraSettings(pixel_format="Mono8")


def median_of(fn: Callable[[], float], repeats: int) -> float:
    return statistics.median(fn() for _ in range(repeats))


def timed(fn: Callable[[], object]) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def view_of(cell: SimulatedCell, cfg: CellConfig, target: str) -> np.ndarray:
    model = cfg.model()
    p = cfg.spheres_part_mm[target]
    qs = candidates.random_configurations(
        model, model.nominal_x(), p, 60, np.random.default_rng(1)
    ).q_deg
    c = cell.centre_in_sensor(qs, p, 0.0)
    lateral = np.where(cell.spec.volume.contains(c), np.hypot(c[:, 0], c[:, 1]), np.inf)
    return np.asarray(qs[int(np.argmin(lateral))])


def set_volts(galvo: Galvo, volts: float) -> None:
    galvo.set_volts(volts)


def motion_error_s(cell: SimulatedCell, scale: float) -> float:
    """Median (sim time of move_joints - expected motion time) [sim s] for 2 s moves."""
    errors = []
    with (
        SimLine(cell, SimLineSetup(scale=scale, clock="scaled", camera=False)) as line,
        registry.open_robot(line.urls["robot"]) as robot,
    ):
        for k in range(5):
            target = HOME + np.array([35.0 if k % 2 == 0 else 0.0, 0, 0, 0, 0, 0])
            t0 = line.clock.monotonic()
            robot.move_joints(target, speed_pct=10)
            errors.append(line.clock.monotonic() - t0 - line.controller.motion_durations_s[-1])
    return statistics.median(errors)


def sweep_through_drivers(
    cell: SimulatedCell, cfg: CellConfig
) -> tuple[float, float, float, float]:
    """(grab s through Aravis, direct render s, render at a new pose s, sweep s); prints the
    centre error."""
    q = view_of(cell, cfg, "P2")
    p = cfg.spheres_part_mm["P2"]
    with (
        SimLine(cell, SimLineSetup(scale=1.0, clock="scaled")) as line,
        registry.open_robot(line.urls["robot"]) as robot,
        registry.open_galvo(line.urls["galvo"]) as galvo,
        registry.open_camera(line.urls["camera"], settings=FULL, timeout_s=5.0) as camera,
    ):
        robot.move_joints(q, speed_pct=100)
        grab_s = median_of(lambda: timed(camera.grab), 5)
        render_s = median_of(lambda: timed(lambda: cell.render_frame_v(1296, 966, 1e4, 0, 0)), 5)
        c = cell.centre_in_sensor(q, p)[0]
        scene_s = median_of(lambda: timed(lambda: sphere_scene(cell.sensor, c, 15.0)), 5)
        commands = cell.sweep_commands_v
        t = time.perf_counter()
        frames = []
        for v in commands:
            set_volts(galvo, float(v))
            frames.append(camera.grab().image)
        sweep_s = time.perf_counter() - t
        truth = cell.centre_in_sensor(q, p)[0]
    m = measure_sphere_from_sweep(np.stack(frames), commands, default_sensor_model())
    error_um = 1000.0 * np.linalg.norm(m.c_sensor_mm - truth)
    print(f"sweep of {len(commands)} frames through the drivers: centre error {error_um:.1f} um")
    return grab_s, render_s, render_s + scene_s, sweep_s


def main() -> None:
    cfg = load_cell(None)
    cell = make_cell(cfg, seed=0)
    _ = cell.sensor.pixel_rays
    print("| what | median |")
    print("|---|---|")
    for settings in (SimLineSetup(camera=False), SimLineSetup(camera=True)):

        def start_close(settings: SimLineSetup = settings) -> float:
            return timed(lambda: SimLine(cell, settings).start().close())

        s = median_of(start_close, 5)
        print(f"| SimLine start + close, camera={settings.camera} | {1000 * s:.0f} ms |")
    for scale in (1.0, 10.0, 60.0):
        e = motion_error_s(cell, scale)
        print(f"| move_joints sim time - motion time, scale {scale:g} | {1000 * e:.0f} sim ms |")
    grab_s, render_s, new_pose_s, sweep_s = sweep_through_drivers(cell, cfg)
    print(f"| one lit frame: render at a new pose (scene built) | {1000 * new_pose_s:.0f} ms |")
    print(f"| one lit frame: render, robot standing (scene reused) | {1000 * render_s:.0f} ms |")
    print(f"| one lit frame: grab through Aravis | {1000 * grab_s:.0f} ms |")
    print(f"| ratio grab / render (same run) | {grab_s / render_s:.2f} |")
    print(f"| sweep of 24 (galvo + grab each) | {sweep_s:.2f} s |")
    line = SimLine(cell, SimLineSetup(camera=False)).start()
    try:
        cell.set_joints_deg(view_of(cell, cfg, "P2"))
        g = median_of(lambda: timed(lambda: line.geometric_centre("P2")), 50)
    finally:
        line.close()
    print(f"| geometric_centre | {1e6 * g:.0f} us |")


if __name__ == "__main__":
    main()
