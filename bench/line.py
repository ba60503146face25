"""Benchmarks of the in-line service (issue 11): the latency from the PLC's window bit to the
robot's first motion command at a 10 ms poll, the CPU of the waiting service, and one sweep of
24 frames -> sphere centre (vision only, one core).

    nice -n 5 .venv/bin/python bench/line.py [--windows 30] [--idle-s 5]

The service runs with the real clock on in-process fakes: a PLC whose window bit the benchmark
flips (recording the time of the flip) and a fake robot that records the time of its first
motion primitive. Medians of repeated measurements.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.threads import limit_blas_threads

limit_blas_threads()

import numpy as np

from app.config import load_cell
from app.config.line import LineSettings
from app.line.measure import GeometricSensor
from app.line.schedule import Schedule
from app.line.service import Service
from app.line.settings import ServiceSettings
from app.line.station import Station
from app.sim.cell import make_cell
from drivers.plc import Plc, PlcInputs, decode_outputs, encode_inputs
from drivers.robot import FloatArray
from fakes.devices import FakeRobot
from tests.line.helpers import plan_for


class BenchPlc(Plc):
    def __init__(self) -> None:
        super().__init__()
        self.window_bit = False
        self.last_done = False
        self.beat = 0
        self.last_words = (0, 0)
        self.opened_t = 0.0
        self.done = threading.Event()

    def _connect(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read_input_words(self) -> tuple[int, int]:
        self.beat = (self.beat + 1) & 0xFFFF
        return encode_inputs(PlcInputs(self.window_bit, True, self.beat))

    def _write_output_words(self, words: tuple[int, int]) -> None:
        outputs = decode_outputs(words)
        if outputs.done and not self.last_done:
            self.done.set()
        self.last_done = outputs.done
        self.last_words = words

    def _read_output_words(self) -> tuple[int, int]:
        return self.last_words

    def open_window(self) -> None:
        self.done.clear()
        self.opened_t = time.perf_counter()
        self.window_bit = True


class BenchRobot(FakeRobot):
    first_move_t: float | None = None

    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None:
        if self.first_move_t is None:
            self.first_move_t = time.perf_counter()
        super()._move(q_deg, speed_pct, timeout_s)


def _service(
    state: Path, poll_s: float, plc: BenchPlc | None = None, **settings: Any
) -> tuple[Service, BenchPlc, BenchRobot]:
    """The service on in-process fakes (`plc`: a BenchPlc or a subclass; `settings`: more
    ServiceSettings, e.g. opcua=, and LineSettings as line_*=)."""
    cfg = load_cell(None)
    cell = make_cell(cfg, 3)
    robot = BenchRobot(cell, time_scale=0.002)
    robot.open()
    plc = plc or BenchPlc()
    plc.open()
    line_kw = {k[5:]: settings.pop(k) for k in list(settings) if k.startswith("line_")}
    line = LineSettings(poll_s=poll_s, window_s=8.0, **line_kw)
    service_settings = ServiceSettings(state_dir=state, line=line, **settings)
    svc = Service(
        Station(robot=robot, plc=plc),
        GeometricSensor(cell.measure_target, duration_s=1.2),
        Schedule(plan_for(3), line),
        cfg.spheres_part_mm,
        cfg.model(),
        cfg.model().nominal_x(),
        settings=service_settings,
    )
    return svc, plc, robot


def window_latency(n: int, poll_s: float) -> list[float]:
    with tempfile.TemporaryDirectory() as tmp:
        svc, plc, robot = _service(Path(tmp), poll_s)
        thread = threading.Thread(target=svc.run)
        thread.start()
        out: list[float] = []
        try:
            for _ in range(n + 1):
                while svc.watch.opened_t is not None:  # until the service saw it closed
                    time.sleep(poll_s)
                time.sleep(poll_s * np.random.default_rng(len(out)).uniform())  # random phase
                robot.first_move_t = None
                plc.open_window()
                assert plc.done.wait(10.0), svc.status()
                assert robot.first_move_t is not None
                out.append(robot.first_move_t - plc.opened_t)
                plc.window_bit = False
        finally:
            svc.stop()
            thread.join()
            robot.close()
            plc.close()
    return out[1:]  # the first window warms the caches


def idle_cpu(seconds: float, poll_s: float) -> float:
    """CPU time of the waiting service per wall second (window never opens)."""
    with tempfile.TemporaryDirectory() as tmp:
        svc, plc, robot = _service(Path(tmp), poll_s)
        thread = threading.Thread(target=svc.run)
        thread.start()
        time.sleep(0.5)
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        time.sleep(seconds)
        r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        svc.stop()
        thread.join()
        robot.close()
        plc.close()
    cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return cpu / (t1 - t0)


def sweep_to_centre(repeats: int) -> tuple[list[float], list[float], float]:
    """Wall and CPU seconds of each repeat, and the centre error [mm]."""
    import cv2

    from vision.measure import measure_sphere_from_sweep
    from vision.sensor_model import default_sensor_model

    cv2.setNumThreads(1)  # one core, as the figure says
    cfg = load_cell(None)
    cell = make_cell(cfg, 3)
    q = plan_for(3)["P1"][0]
    frames, commands, _ = cell.render_sweep(q, cfg.spheres_part_mm["P1"])
    model = default_sensor_model()
    times, cpu, err = [], [], 0.0
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        m = measure_sphere_from_sweep(frames, commands, model)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        err = float(
            np.linalg.norm(
                m.c_sensor_mm - cell.centre_in_sensor(q[None], cfg.spheres_part_mm["P1"])[0]
            )
        )
    return times, cpu, err


def print_table(rows: list[tuple[str, Any, str]]) -> None:
    """The benchmark's rows (measure, value, target) as an aligned table."""
    width = max(len(r[0]) for r in rows)
    print(f"{'measure':<{width}}  value  target")
    for name, value, target in rows:
        print(f"{name:<{width}}  {value}  {target}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--windows", type=int, default=30)
    p.add_argument("--idle-s", type=float, default=5.0)
    p.add_argument("--repeats", type=int, default=10)
    args = p.parse_args(argv)
    rows: list[tuple[str, Any, str]] = []
    lat = window_latency(args.windows, 0.01)
    rows.append(
        (
            "window bit -> first motion command, 10 ms poll [ms]",
            f"{1000 * statistics.median(lat):.1f} (p90 {1000 * np.percentile(lat, 90):.1f},"
            f" max {1000 * max(lat):.1f}, n={len(lat)})",
            "<= 30",
        )
    )
    for poll in (0.01, 0.1):
        rows.append(
            (
                f"idle CPU of the waiting service, {1000 * poll:g} ms poll [% of a core]",
                f"{100 * idle_cpu(args.idle_s, poll):.1f}",
                "",
            )
        )
    times, cpu, err = sweep_to_centre(args.repeats)
    rows.append(
        (
            "one sweep of 24 frames -> centre, one core [ms]",
            f"{1000 * statistics.median(times):.1f} (min {1000 * min(times):.1f}, CPU "
            f"{1000 * statistics.median(cpu):.1f}, n={len(times)}; centre error "
            f"{1000 * err:.1f} um)",
            "<= 60",
        )
    )
    print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
