"""Helpers of the service tests: the simulated line of in-process fakes on a SimulatedCell
(geometric sensor) in virtual time (the robot's motions, the sensor's sweep and the service's
own waits make it pass: what the service does does not depend on the machine's load; paced at
x50 for the tests that talk to it while it runs), and waiting on the service's events (never
sleeping)."""

from __future__ import annotations

import queue
import sqlite3
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config import load_cell
from app.config.line import LineSettings, RecalibSettings
from app.line.measure import GeometricSensor, Rejected, SphereSensor
from app.line.schedule import Schedule
from app.line.service import Service
from app.line.settings import ServiceSettings
from app.line.station import Station
from app.sim.cell import make_cell, validation_set
from app.sim.cold_calibration import random_schedule
from calib.identify import IdentificationResult, Measurements, identify
from calib.model import SystemModel
from drivers.plc import decode_inputs, decode_outputs, encode_inputs
from fakes.cell import SimulatedCell
from fakes.cell_spec import NotVisible
from fakes.clock import VirtualClock
from fakes.devices import ClampCycle, FakePlc, FakeRobot

F64 = NDArray[np.float64]
SCALE = 0.02  # the fakes' time_scale (real seconds per simulated second on the wall clock)


class LinePlc(FakePlc):
    """The fake PLC plus what the tests watch: window edges (a condition to wait on), the
    number of stored measurements at each `done` edge, and a window withdrawn as soon as the
    robot leaves home (`withdraw_on_motion`)."""

    def __init__(self, cycle: ClampCycle | None = None, **kw: Any) -> None:
        super().__init__(cycle, **kw)
        self.edges = 0
        self.changed = threading.Condition()
        self.rows_at_done: list[int] = []
        self.db_path: Path | None = None
        self.world: SimulatedCell | None = None
        self.withdraw_on_motion = False
        self.on_done: Callable[[int], None] | None = None  # called with the rows at done
        self._was_open = False

    def _read_input_words(self) -> tuple[int, int]:
        inputs = decode_inputs(super()._read_input_words())
        if self.withdraw_on_motion and self.world is not None and inputs.window_open:
            home = np.array(LineSettings().home_deg)
            if np.max(np.abs(self.world.joints_deg() - home)) > 1.0:
                inputs = replace(inputs, window_open=False)
        if inputs.window_open and not self._was_open:
            with self.changed:
                self.edges += 1
                self.changed.notify_all()
        self._was_open = inputs.window_open
        return encode_inputs(inputs)

    def _write_output_words(self, words: tuple[int, int]) -> None:
        outputs = decode_outputs(words)
        if outputs.done and not self.received.done and self.db_path is not None:
            db = sqlite3.connect(f"file:{self.db_path}?mode=ro", uri=True)
            rows = int(db.execute("SELECT COUNT(*) FROM measurements").fetchone()[0])
            db.close()
            self.rows_at_done.append(rows)
            if self.on_done is not None:
                self.on_done(rows)
        super()._write_output_words(words)

    def wait_edges(self, n: int, timeout_s: float = 10.0) -> None:
        """Wait until `n` more windows have opened."""
        with self.changed:
            target = self.edges + n
            assert self.changed.wait_for(lambda: self.edges >= target, timeout_s)


@cache
def plan_for(seed: int, n_each: int = 6) -> dict[str, F64]:
    """n_each configurations per sphere that the nominal model plans and the true cell sees."""
    cfg = load_cell(None)
    out = random_schedule(cfg, make_cell(cfg, seed), seed, n_each)
    assert all(len(q) == n_each for q in out.values())
    return out


@dataclass
class Line:
    """A service on fakes: cell (truth), robot, plc, clock, settings, service."""

    cell: SimulatedCell
    model: SystemModel
    robot: FakeRobot
    plc: LinePlc
    service: Service
    clock: VirtualClock
    thread: threading.Thread | None = None
    events: queue.Queue[dict[str, Any]] = field(default_factory=queue.Queue)

    def start(self) -> Line:
        self.events = self.service.bus.subscribe()
        self.thread = threading.Thread(target=self.service.run, daemon=True)
        self.thread.start()
        return self

    def stop(self) -> None:
        self.service.stop()
        if self.thread is not None:
            self.thread.join(20)
            assert not self.thread.is_alive()

    def wait(
        self, pred: Callable[[dict[str, Any]], bool], timeout_s: float = 10.0
    ) -> dict[str, Any]:
        """The first event from now on that satisfies pred (AssertionError after timeout)."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            assert remaining > 0, "timed out waiting for a service event"
            try:
                ev = self.events.get(timeout=remaining)
            except queue.Empty:
                continue
            if pred(ev):
                return ev

    def windows(self, n: int, timeout_s: float = 15.0) -> list[dict[str, Any]]:
        return [self.wait(lambda e: e["event"] == "window", timeout_s) for _ in range(n)]

    def close(self) -> None:
        if self.thread is not None and self.thread.is_alive():
            self.stop()
        if self.thread is None:  # never run: run() closes the database itself
            self.service.store.close()
        self.robot.close()
        self.plc.close()


def line_settings(**kw: Any) -> LineSettings:
    base = LineSettings(poll_s=0.25, heartbeat_timeout_s=10.0, window_s=8.0, margin_s=0.5)
    return replace(base, **kw)


def make_line(
    state_dir: Path,
    *,
    seed: int = 3,
    cycle: ClampCycle | None = None,
    line: LineSettings | None = None,
    recalib: RecalibSettings | None = None,
    x_initial: F64 | None = None,
    sensor: Callable[[SimulatedCell], SphereSensor] | None = None,
    robot_class: type[FakeRobot] = FakeRobot,
    model: SystemModel | None = None,
    plan: dict[str, F64] | None = None,
    initial_residuals: dict[str, Any] | None = None,
    **cell_overrides: Any,
) -> Line:
    """A service on fakes; its model rigid unless given ([service] model: compliant by default
    in a cell file), and its estimator the batch one unless `recalib` says otherwise; its
    schedule `plan` (default `plan_for(seed)`); `initial_residuals` as Service's (the initial
    version's covariance and workspace validation)."""
    cfg = load_cell(None)
    cell = make_cell(cfg, seed, **cell_overrides)
    model = model or cfg.model()
    clock = VirtualClock(pace=1.0 / SCALE)  # watched live (the socket, restarts): paced x50
    cycle = cycle or ClampCycle(period_s=12.0, window_s=8.0, beat_s=0.5, time_scale=SCALE)
    robot = robot_class(cell, time_scale=SCALE, clock=clock).open()
    plc = LinePlc(cycle, clock=clock)
    plc.open()
    plc.world, plc.db_path = cell, state_dir / "rvis.db"
    settings = ServiceSettings(
        state_dir=state_dir,
        line=line or line_settings(window_s=cycle.window_s),
        recalib=recalib or RecalibSettings(estimator="batch"),
    )

    def sweep(target: str, sweep_s: float = 1.2) -> F64:
        """The sweep's time, as the simulated line's geometric path; a sphere out of the view
        a rejected measurement, as there (app.sim.line_run)."""
        clock.elapse(sweep_s)
        try:
            return cell.measure_target(target)
        except NotVisible as exc:
            raise Rejected(f"NotVisible: {exc}") from exc

    sphere_sensor = GeometricSensor(sweep, duration_s=1.2) if sensor is None else sensor(cell)
    schedule = Schedule(plan_for(seed) if plan is None else plan, settings.line)
    x0 = model.nominal_x() if x_initial is None else x_initial
    service = Service(
        Station(robot=robot, plc=plc),
        sphere_sensor,
        schedule,
        cfg.spheres_part_mm,
        model,
        x0,
        clock=clock,
        settings=settings,
        initial_residuals=initial_residuals,
    )
    return Line(cell, model, robot, plc, service, clock)


KNOCK_SEED = 3  # the knocked line's cell and plan


def calibrated_x(cell: SimulatedCell) -> F64:
    """Parameters identified from the plan's 24 views of the cell (as a past service did)."""
    return calibration(cell).x


def calibration(cell: SimulatedCell, temp_c: float | None = None) -> IdentificationResult:
    """The rigid identification on the plan's 24 views of the cell; with `temp_c`, the cell
    at that temperature and every view recorded with it (as a PLC that provides it does)."""
    cfg = load_cell(None)
    if temp_c is not None:
        cell.temp_c = temp_c
    qs, cs, ps, ids = [], [], [], []
    for tid, q_all in plan_for(KNOCK_SEED).items():
        for q in q_all:
            p = cfg.spheres_part_mm[tid]
            qs.append(q)
            cs.append(cell.measure_point(q, p))
            ps.append(p)
            ids.append(tid)
    temps = None if temp_c is None else np.full(len(ids), temp_c)
    data = Measurements(np.array(qs), np.array(cs), np.array(ps), tuple(ids), temps)
    return identify(cfg.model(), data)


#: The simulated cell's noise before its robot had a repeatability (issue 38 item 9): 20 um of
#: isotropic Gaussian noise per axis of the sensor frame, the robot repeating exactly. The
#: knock tests of the service (`knock_line`) run on it, as their expectations and the service's
#: drift and step settings were set there. On the robot's repeatability (RP 0.07 mm, about 23 um
#: per axis with the 5 um sensor, shaped as a pose error) seed 3's overall residual chart raises
#: a false alarm in the 4th window (EWMA 0.052 > 0.050 mm) and the change charts do not watch
#: after 6 windows; a sensor correction's predicted uncertainty passes step_max_std_mm only
#: after about 4 windows (tests/sim/test_line_bodies.py): the settings' tuning on that world is
#: open, these tests pin the world they were written for.
ISOTROPIC_NOISE: dict[str, Any] = {"repeatability_mm": 0.0, "sensor_noise_mm": 0.02}


def knock_line(
    tmp_path: Path, recalib: RecalibSettings | None, *, slots_per_window: int = 8
) -> tuple[Line, F64, Any]:
    """A line with long windows (8 slots each by default) starting from parameters identified
    on the plan's views, and 30 validation positions: (line, those parameters, validation
    set); the knock is the test's (`ln.cell.set_timeline`). Its cell's noise is
    ISOTROPIC_NOISE."""
    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    probe = make_line(tmp_path / "probe", **ISOTROPIC_NOISE)
    x_good = calibrated_x(probe.cell)
    probe.close()
    ln = make_line(
        tmp_path / "state",
        cycle=cycle,
        line=line_settings(window_s=32.0, slots_per_window=slots_per_window),
        recalib=recalib,
        x_initial=x_good,
        **ISOTROPIC_NOISE,
    )
    val = validation_set(ln.cell, load_cell(None), ln.model, x_good, 30, np.random.default_rng(4))
    return ln, x_good, val


def true_errors_mm(ln: Line, val: Any, x: F64) -> F64:
    """True Euclidean errors [mm] at the validation positions with parameters x (the cell's
    truth, noise-free)."""
    q = val.measurements.q_deg
    c = np.array(
        [
            ln.cell.centre_in_sensor(qi[None], p)[0]
            for qi, p in zip(q, val.truth_p_part_mm, strict=True)
        ]
    )
    e = ln.model.points_part(x, q, c) - val.truth_p_part_mm
    return np.asarray(np.linalg.norm(e, axis=1), dtype=np.float64)


def true_rms(ln: Line, val: Any, x: F64) -> float:
    """True RMS error [mm] at the validation positions with parameters x (the cell's truth)."""
    return float(np.sqrt(np.mean(true_errors_mm(ln, val, x) ** 2)))
