"""The in-line service on the simulated line: what `rvis run --sim` and `rvis tui --sim` start.

The simulated line (fakes/line.py) runs every device peer on loopback from one simulated cell
whose truth drifts with time (warm-up, an optional knock of the sensor mount); the service opens
them through the real drivers (drivers.registry), exactly as on a real cell, with the line's
virtual clock (time passes by what is simulated, so a seed gives one run; paced for a person
who watches). The service starts from a commissioning calibration of the cold cell (an offline
identification of 4 spheres x 6 random views, as `rvis simulate` + `rvis identify` would give)
and measures the schedule's configurations in the clamp windows. After every window the true
error of the parameters in force is evaluated at the line's validation positions (the truth is
known here, never to the service): the one truth of app/sim/truth.py, points measured through the
sensor model in use (rendered) or the true centres (geometric), mapped with the parameters.
The line's set-up from the cell file and the state directory is app/sim/line_setup.py; what a
run reports (a record per window, the summary) app/sim/line_records.py.
"""

from __future__ import annotations

import bisect
import contextlib
import dataclasses
import queue
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.errors import InputError
from app.formats.params import carried_from_json
from app.line.body_cycle import BodySetup
from app.line.measure import SphereSensor, SweepSensor
from app.line.recalib import Recalibrator
from app.line.schedule import Schedule
from app.line.service import Service
from app.line.statedir import StateDir
from app.line.states import AlarmCode, State
from app.line.station import Station, cell_guard
from app.line.store import Store
from app.sim.cell import make_cell, true_sensor_model
from app.sim.cold_calibration import commissioned, random_schedule
from app.sim.line_records import LineFaulted, SimRunSummary, WindowRecord
from app.sim.line_setup import (
    continued_epoch,
    geometric_sensor,
    service_settings,
    simline_settings,
    with_simulated_plc,
    world_of,
)
from app.sim.truth import EndToEndTruth, rmse_or_nan, true_errors_each_mm, true_rmse_mm
from calib.compliance import CompliantModel, carry
from fakes.clock import VirtualClock
from fakes.line import SimLine
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]


#: silences of `events_until`'s timeout in a row while this process computes, before a hang
BUSY_SILENCES = 10


class _Held(Exception):
    """The service holds the cell for maintenance, or sits in a FAULT nobody will clear: no
    window will come."""


def _held_for_maintenance(event: dict[str, Any]) -> bool:
    """The service raised the `maintenance` alarm: the cell holds until a procedure."""
    return event["event"] == "alarm" and event.get("code") == AlarmCode.MAINTENANCE


class SimulatedLineRun:
    """`with SimulatedLineRun(cfg, state_dir, seed=...) as run: run.run_windows(n)`.

    The line runs in virtual time (fakes.clock.VirtualClock): as fast as the CPU, or paced at
    `pace` sim seconds per real second for a person who watches. `run_windows(n)` holds the
    service after its n-th window (its loop waits there and time stands) until the next
    `run_windows` or `close`: what is evaluated then is the same in every run of a seed."""

    def __init__(
        self,
        cfg: CellConfig,
        state_dir: str | Path,
        *,
        seed: int = 0,
        geometric: bool = False,
        plan: Path | None = None,
        sensor_model: SensorModel | None = None,
        pace: float | None = None,
        start_epoch: float | None = None,
        waiting: Callable[[str], None] | None = None,
        bodies: bool = True,
        attended: bool = False,
    ) -> None:
        """sensor_model: the sensor calibration the rendered line measures with (default: the
        true sensor's, a perfect calibration); unused on the geometric path. pace: sim seconds
        per real second (None: as fast as the CPU); start_epoch: the Unix time of sim time 0
        (None: now, to the whole second); waiting: told in one line, at once, when the rendered
        line's camera must wait for another simulation's (as long as that one runs); bodies:
        measure the bodies of the state directory's feature plan, if it has one (False: spheres
        only, as `rvis run --sim --no-bodies`); attended: someone can clear a FAULT (`rvis ctl
        reset` on the service's socket), so `run_windows` waits through one; unattended (an
        experiment) a FAULT the service does not leave by itself within a silence ends the run,
        its alarm in the summary's `fault`."""
        cfg = with_simulated_plc(cfg)
        self.cfg, self.state_dir, self.seed = cfg, Path(state_dir), seed
        self.cell = make_cell(world_of(cfg, state_dir), seed=seed)
        # the service's clock never goes back: on a state directory with a history, the
        # simulated line's time starts where that history ends (else its records would
        # interleave with an earlier run's, which ran ahead of the wall clock)
        epoch, world_s = continued_epoch(self.state_dir, start_epoch)
        setup = simline_settings(cfg, geometric=geometric, pace=pace, start_epoch=epoch)
        setup = dataclasses.replace(setup, world_s=world_s)  # warm, knocked, counted as left
        if waiting is not None:
            setup = dataclasses.replace(setup, camera_wait_s=None, camera_on_wait=waiting)
        self.line = SimLine(self.cell, setup)
        self.pace = pace
        self._body_cpu_s = 0.0  # the rendered path's bodies: set with them (`_bodies`)
        self.settings = service_settings(cfg, self.state_dir)
        self.geometric, self.plan, self.measures_bodies = geometric, plan, bodies
        # the model the service identifies and the true error is computed in: [service] model,
        # or the commissioning's compliant one under a rigid [service] model (the service keeps
        # a compliant version's compliance: calib.compliance.carry)
        commission_model = cfg.commissioning_model()
        compliant = isinstance(commission_model, CompliantModel)
        self.model = commission_model if compliant else cfg.service_model()
        if not geometric and sensor_model is None:
            sensor_model = true_sensor_model(self.cell.sensor)
        self.sensor_model = None if geometric else sensor_model
        self._commands = self.settings.sweep.commands_v()
        self._truths: dict[int, EndToEndTruth] = {}  # by the true sensor (`truth_at`)
        first = StateDir(self.state_dir).version_file(1)
        # the parameters the service starts from in a new state directory: the cold cell's
        # calibration, measured as the line measures (a state directory with its first
        # version, commissioned or run before, starts from what it holds: `load_in_force`)
        self.commissioning_residuals: dict[str, Any] | None = None
        if first.is_file():
            self.x_commissioning = carried_from_json(self.model, first)[1]
        else:
            self.x_commissioning = self._cold_calibration(cfg, seed, commission_model)
        self.summary = SimRunSummary()
        self._t_open: list[float] = []  # the clock time each record's window began
        self.held_for_maintenance = False  # the service raised `maintenance`: it holds
        self.attended = attended
        self._versions: dict[int, F64] = {}
        self._stack = contextlib.ExitStack()
        self.thread: threading.Thread | None = None
        self._gate = threading.Condition()
        self._hold_at = float("inf")  # hold the service after this many windows of this run
        self._windows_before = 0
        self._held = False
        self._closing = False
        self._loop_ended = False

    @property
    def clock(self) -> VirtualClock:
        """The line's (and the service's) clock."""
        assert self.line.virtual is not None
        return self.line.virtual

    def __enter__(self) -> SimulatedLineRun:
        try:
            self._start()
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _start(self) -> None:
        line = self._stack.enter_context(self.line)
        urls = dict(line.urls)
        if self.geometric:
            urls.pop("camera", None)
            urls.pop("galvo", None)
        trace = self.cfg.devices.wire_trace(StateDir(self.state_dir).wire_trace, every_device=True)
        station = Station.open(urls, guard=cell_guard(self.cfg), trace=trace)
        self._stack.callback(station.close)
        sensor: SphereSensor
        if self.geometric:
            sensor = geometric_sensor(line, self.settings.sweep.duration_s)
        else:
            assert station.camera is not None and station.galvo is not None
            assert self.sensor_model is not None
            sensor = SweepSensor(
                station.camera, station.galvo, self.sensor_model, self.settings.sweep
            )
        self._station, self._sensor, self._body_setup = station, sensor, self._bodies(line)
        self._new_service()
        if self.service.params.version_path(1).is_file():
            self.x_commissioning = self._x_of(1)
        self.summary.true_rmse_start_mm = self.true_rmse_mm(self.service.x)

    def _new_service(self) -> None:
        """A service on the run's station, sensor and bodies, from the state directory (its
        schedule from the plan, or the seed's random one; where it stopped: the store's)."""
        if self.plan is not None:
            schedule = Schedule.from_plan(self.plan, self.settings.line)
        else:
            n_each = self.cfg.calibration.configs_per_sphere
            schedule = Schedule(
                random_schedule(self.cfg, self.cell, self.seed, n_each), self.settings.line
            )
        recalibrator = Recalibrator(cost_s=self.cfg.simline.identification_s, clock=self.clock)
        recalibrator.prestart()
        self.service = Service(
            self._station,
            self._sensor,
            schedule,
            self.cfg.spheres_part_mm,
            self.model,
            self.x_commissioning,
            clock=self.clock,
            settings=self.settings,
            recalibrator=recalibrator,
            initial_residuals=self.commissioning_residuals,
            bodies=self._body_setup,
        )
        self.service.after_window = self._hold
        # a restarted state directory's service counts its windows on: hold by this run's
        done = int(self.service.decision.counters.get("windows", 0))
        self._windows_before = done - self.summary.windows
        self.events = self.service.bus.subscribe(every=True)

    def restart_service(self) -> None:
        """The service held after its window stopped and started again on its state directory
        (a process restart: the estimator replays the version's measurements), the world, its
        clock and the devices going on; the next `run_windows` counts on from this run's."""
        self.close_service()
        self._closing = self._held = False
        self.thread = None
        self._new_service()

    def close_service(self) -> None:
        """Stop the service (it holds after its window: let it go) and wait for its loop."""
        if self.thread is not None and self.thread.is_alive():
            self.service.stop()
            with self._gate:
                self._closing = True
                self._gate.notify_all()
            self.thread.join(60)

    def _cold_calibration(self, cfg: CellConfig, seed: int, commission_model: Any) -> F64:
        """The cold cell's calibration (`commissioned`, the sensor as built measured with the
        sensor model in use) in the run's model; its residuals, validation and covariance
        kept for the new directory's first version (`commissioning_residuals`)."""
        cold = EndToEndTruth(self.cell.sensor_at(0.0), self.sensor_model, self._commands)
        done, validation_mm = commissioned(cfg, seed, cold)
        self.commissioning_residuals = {
            "n_measurements": int(done.residuals_mm.shape[0]),
            "rms_mm": done.rms_mm,
            "n_parameters": len(done.active),
            # what the commissioning's workspace step would have measured (app.line.accuracy)
            "validation_errors_mm": validation_mm.tolist(),
            # the identification's covariance: the estimator's prior (app.line.jumps)
            "covariance": {
                "active": list(done.active),
                "cov": (done.corr * np.outer(done.std, done.std)).tolist(),
            },
        }
        x: F64 = carry(self.model, commission_model, done.x, done.temp_c)[1]
        return x

    def truth_at(self, t_s: float | None = None) -> EndToEndTruth:
        """The end-to-end truth at sim time t_s (default: now): the true sensor the cell has
        then (a sensor replaced by a maintenance event is another one) measured with the
        sensor model the line measures with."""
        sensor = self.cell.sensor_at(t_s)
        truth = self._truths.get(id(sensor))
        if truth is None:
            truth = EndToEndTruth(sensor, self.sensor_model, self._commands)
            self._truths[id(sensor)] = truth
        return truth

    @property
    def truth(self) -> EndToEndTruth:
        """The end-to-end truth now (`truth_at`)."""
        return self.truth_at(None)

    def _bodies(self, line: SimLine) -> BodySetup | None:
        """The bodies the line clamps measured as the state directory's feature plan says (none
        without a plan), built by the seed's process, on the line's path (app.sim.bodies: the
        rendered one through the sensor model the line measures with)."""
        from app.line.body_cycle import feature_plan
        from app.sim.bodies import LineFeatureSensor, SimulatedBodies
        from fakes.body import BuildProcess, ClampSettings
        from vision.sensor_model import default_sensor_model, load_sensor_model

        paths = StateDir(self.state_dir)
        plan = feature_plan(paths.root, self.cfg.T_part_base) if self.measures_bodies else None
        if plan is None:
            return None
        # a rendered body's sweeps take the CPU seconds each, with no event between them
        self._body_cpu_s = 0.0 if self.geometric else 5.0 * len(plan.features)
        s = self.cfg.simline
        if s.shift_feature and s.shift_feature not in {f.id for f in plan.features}:
            raise InputError(
                f"[simline] shift_feature: no feature {s.shift_feature!r} in {plan.source}",
                field="shift_feature",
            )
        shift = (s.shift_feature, s.shift_at_body, s.shift_mm) if s.shift_feature else None
        process, clamping = BuildProcess(seed=self.seed, shift=shift), ClampSettings()
        bodies = SimulatedBodies(self.cell, plan, process, clamping, self.sensor_model)
        model = load_sensor_model(paths.sensor) if paths.sensor.is_file() else None
        return BodySetup(plan, LineFeatureSensor(line, bodies), model or default_sensor_model())

    def true_rmse_mm(self, x: F64, t_s: float | None = None) -> float:
        """The end-to-end true error [mm, RMS] of parameters x at the validation positions at
        sim time t_s (default now)."""
        return true_rmse_mm(self.line, self.truth_at(t_s), self.model, x, t_s)

    def start_service(self) -> None:
        self._loop_ended = False
        self.thread = threading.Thread(target=self._serve, name="rvis-service", daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        """The service's loop; when it ends (stopped, or an internal error), whoever waits for
        it to hold hears so at once instead of at the end of its timeout (a stop took 11 s)."""
        try:
            self.service.run()
        finally:
            with self._gate:
                self._loop_ended = True  # the thread is still alive here: is_alive() says no later
                self._gate.notify_all()

    # -- holding the service between windows ----------------------------------------------------
    def _hold(self) -> None:
        """In the service's loop after each window: wait there while it has measured the
        windows asked for (its virtual time stands meanwhile)."""
        with self._gate:
            while (
                self.service.decision.counters["windows"] - self._windows_before >= self._hold_at
                and not self._closing
            ):
                self._held = True
                self._gate.notify_all()
                self._gate.wait()
            self._held = False

    def _held_or_gone(self, timeout_s: float) -> None:
        """Wait until the service holds after its window (or its loop ended)."""

        def still() -> bool:
            return self._held or self._loop_ended or self.thread is None

        with self._gate:
            while not self._gate.wait_for(still, timeout=timeout_s):
                if not self._quiet_by_itself():
                    raise TimeoutError(f"the service did not hold in {timeout_s:g} s")

    def events_until(
        self,
        stop: Callable[[dict[str, Any]], bool],
        timeout_s: float,
        quiet_ok: Callable[[], bool] = lambda: False,
    ) -> Iterator[dict[str, Any]]:
        """The service's events until `stop(event)` is true. After timeout_s of silence:
        TimeoutError (a service that hangs), unless `quiet_ok()` says the silence is the
        service's own (held in FAULT or paused until an operator acts: keep waiting), or this
        process spent a tenth of it computing (a body rendered on a loaded machine: a hung
        service spends none), at most BUSY_SILENCES times in a row."""
        busy = 0
        while True:
            cpu0 = time.process_time()
            try:
                event = self.events.get(timeout=timeout_s)
            except queue.Empty:
                if quiet_ok():
                    continue
                if time.process_time() - cpu0 >= 0.1 * timeout_s and busy < BUSY_SILENCES:
                    busy += 1
                    continue
                raise TimeoutError(f"no event from the service in {timeout_s:g} s") from None
            busy = 0
            yield event
            if stop(event):
                return

    def _quiet_by_itself(self) -> bool:
        """The service is silent on purpose: in FAULT or paused, waiting for an operator."""
        alive = self.thread is not None and self.thread.is_alive()
        return alive and (self.service.state == State.FAULT or self.service.decision.paused)

    def run_windows(
        self,
        n: int,
        on_window: Callable[[WindowRecord], None] | None = None,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> SimRunSummary:
        """Run the service until n windows have passed (counted from the start) and hold it
        there, or until it holds the cell for maintenance (nothing in this process can end
        that: `rvis maintain`); the summary of the run. `on_event` sees every event of the
        service after it is counted."""
        with self._gate:
            self._hold_at = n
            self._gate.notify_all()
        if self.thread is None:
            self.start_service()
        s = self.summary
        silence_s = (
            10.0 if self.pace is None else 10.0 + 5.0 * self.cfg.simline.period_s / self.pace
        ) + self._body_cpu_s

        def done(event: dict[str, Any]) -> bool:
            return s.windows >= n or event["event"] == "stopped" or _held_for_maintenance(event)

        def quiet() -> bool:
            """Silent on purpose; held for maintenance since its start (a restart), or in a
            FAULT with nobody to reset it (unattended): done."""
            if not self._quiet_by_itself():
                return False
            if self.service.store.active_alarms(code=AlarmCode.MAINTENANCE):
                self.held_for_maintenance = True
                raise _Held
            if not self.attended and self.service.state == State.FAULT:
                store = self.service.store
                alarms = store.active_alarms(code=AlarmCode.DEVICE_FAULT) or store.active_alarms()
                s.fault = str(alarms[-1]["message"]) if alarms else "FAULT"
                raise _Held
            return True

        if s.windows < n:
            with contextlib.suppress(_Held):
                for event in self.events_until(done, silence_s, quiet):
                    self.summary.count(event)
                    self.held_for_maintenance |= _held_for_maintenance(event)
                    if on_event is not None:
                        on_event(event)
                    if event["event"] == "window":
                        record = self._record(event)
                        s.records.append(record)
                        if on_window is not None:
                            on_window(record)
        self.mark_suspect()
        if self.held_for_maintenance or s.fault is not None:  # no window comes: it stops here
            if self.held_for_maintenance:
                held = self.service.store.active_alarms(code=AlarmCode.MAINTENANCE)
                s.maintenance = str(held[-1]["message"]) if held else None
            self.service.stop()
            with self._gate:
                self._gate.wait_for(lambda: self._loop_ended, timeout=silence_s)
        else:
            self._held_or_gone(silence_s)
        s.true_rmse_final_mm = self.true_rmse_mm(self.service.x)
        if s.fault is not None:
            raise LineFaulted(s)
        return s

    def mark_suspect(self) -> None:
        """Each window record's body (the window the PLC opened last before the service's
        window began) and whether it is suspect: `rvis state suspects` lists it (an interval
        may reach back, so once the windows are run), and the bodies' counts in the summary.
        Read from the state directory's database (a service stopped by a signal meanwhile has
        closed its own connection)."""
        store = Store.read_only(self.service.paths.db)
        try:
            listed = {b for s in store.suspects() for b in s["bodies"]}
            rows = [(float(w["t"]), w["body_id"]) for w in store.windows()]
            bodies = store.bodies()
        finally:
            store.close()
        s = self.summary
        s.bodies = len(bodies)
        s.bodies_nok = sum(not b["ok"] for b in bodies)
        s.bodies_undecided = sum(b["n_undecided"] > 0 for b in bodies)
        s.bodies_reevaluated = sum(b["evaluation"] > 0 for b in bodies)
        times = [t for t, _ in rows]
        for record, t_open in zip(self.summary.records, self._t_open, strict=True):
            k = bisect.bisect_right(times, t_open) - 1
            record.body = rows[k][1] if k >= 0 else None
            record.suspect = record.body is not None and record.body in listed

    def _record(self, event: dict[str, Any]) -> WindowRecord:
        """The line after a window, at the sim time of its event: the true error of the
        parameters the service had in force in it (`params_version`: what the bodies measured
        just before the window were measured with; a correction applied right after it shows
        in the next)."""
        truth, epoch = self.line.truth, self.clock.start_epoch
        version = event.get("params_version")
        if version is None:
            version = self.service.version
        t_s = float(event["t"]) - epoch
        e, e_commissioning = true_errors_each_mm(
            self.line,
            self.truth_at(t_s),
            self.model,
            [self._x_of(version), self.x_commissioning],
            t_s,
        )
        u95 = event.get("u95_mm")
        norms = np.linalg.norm(e, axis=1)
        record = WindowRecord(
            window=self.summary.windows,
            t_h=t_s / 3600.0,
            temp_c=truth.temp_c(t_s),
            rmse_mm=rmse_or_nan(e),
            rmse_commissioning_mm=rmse_or_nan(e_commissioning),
            version=version,
            u95_mm=u95,
            within_u95=None if u95 is None or not len(e) else float(np.mean(norms <= u95)),
            p95_mm=float(np.percentile(norms, 95)) if len(e) else float("nan"),
            targets=[self.service.schedule.slots[int(i)].target for i in event.get("slots", ())],
        )
        t_open = float(event.get("t_open", event["t"]))
        self._t_open.append(t_open)  # the window's body: `mark_suspect`
        if "t_open" in event:
            record.t_open_h = (t_open - epoch) / 3600.0
        return record

    def _x_of(self, version: int) -> F64:
        """The parameters of history version `version` (read once), in the run's model."""
        if version not in self._versions:
            path = self.service.params.version_path(version)
            self._versions[version] = carried_from_json(self.model, path)[1]
        return self._versions[version]

    def close(self) -> None:
        self.close_service()
        self._stack.close()
