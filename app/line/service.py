"""The in-line service: the state machine around the cycle, alarms, recalibration and the
operator's commands (DESIGN.md section 6).

    STARTING -> (robot not home: FAULT) -> IDLE -> MEASURING -> IDLE ...
    PAUSED by an operator; FAULT on any device error, left only by an operator's reset.

One thread runs `run()`: it polls the PLC every `poll_s`, runs a window when a fresh one opens,
and between windows executes the operator's commands (queued by the control socket), collects
the background recalibration and applies parameters, so that parameters change only between
windows. On a device error: the robot is stopped, the PLC fault bit set, an alarm raised with
the cause, and nothing moves until `reset`. After a reset the robot comes home in the next
window. `stop()` (SIGTERM) lets a running window finish (the robot comes home), then returns.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Mapping
from concurrent.futures import Future
from enum import StrEnum
from queue import Empty, Queue
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.line.clock import Clock, RealClock
from app.line.cycle import Cycle, WindowWatch
from app.line.drift import DriftMonitor, residual_mm
from app.line.events import EventBus
from app.line.measure import Reading, SphereMeasurer, SphereSensor
from app.line.operator import OperatorCommands
from app.line.params_store import ParamsStore
from app.line.recalib import Recalibrator, RecalJob, RecalOutcome, as_measurements, select_rolling
from app.line.schedule import Schedule, Slot
from app.line.settings import ServiceSettings
from app.line.station import Station
from app.line.store import Store
from app.line.sweeps import SweepArchive
from app.params import plain_document
from calib.model import SystemModel
from drivers.errors import DeviceError

F64 = NDArray[np.float64]


class State(StrEnum):
    STARTING = "starting"
    IDLE = "idle"
    MEASURING = "measuring"
    PAUSED = "paused"
    FAULT = "fault"
    STOPPED = "stopped"


class Service(OperatorCommands):
    """`Service(station, sensor, schedule, spheres, model, x0, clock=, settings=)`; `run()`
    in a thread (or the main one), `stop()` from anywhere; `request()` for commands."""

    def __init__(
        self,
        station: Station,
        sensor: SphereSensor,
        schedule: Schedule,
        spheres_part_mm: Mapping[str, ArrayLike],
        model: SystemModel,
        x_initial: ArrayLike,
        *,
        clock: Clock | None = None,
        settings: ServiceSettings | None = None,
        recalibrator: Recalibrator | None = None,
    ) -> None:
        self.settings = s = settings or ServiceSettings()
        self.clock = clock or RealClock()
        self.station, self.schedule = station, schedule
        self.spheres = {k: np.asarray(v, dtype=np.float64) for k, v in spheres_part_mm.items()}
        s.state_dir.mkdir(parents=True, exist_ok=True)
        self.store = Store(s.state_dir / "rvis.db")
        self.params = ParamsStore(s.state_dir)
        self.sweeps = SweepArchive(s.state_dir / "sweeps", s.raw_sweeps_keep)
        self.bus = EventBus(self.store, self.clock)
        self.model, self.x, self.version = self._load_params(model, np.asarray(x_initial, float))
        self.drift = DriftMonitor(s.drift)
        self.recalibrator = recalibrator or Recalibrator()
        self.watch = WindowWatch(station.plc, self.clock, s.line)
        self.measurer = SphereMeasurer(station.robot, sensor, s.line)
        self.cycle = Cycle(self.watch, self.measurer, schedule, self._position, self._record)
        self.state = State.STARTING
        self.paused = False
        self.counters = {"windows": 0, "overruns": 0, "withdrawn": 0}
        self.pending_calibration: int | None = None
        self.drift_onset_id: int | None = None
        self.new_since_recal = 0
        self.force_recal = False
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._commands: Queue[tuple[str, dict[str, Any], int | None, Future[dict[str, Any]]]]
        self._commands = Queue()
        self.log = logging.getLogger("rvis.line")

    # -- life cycle ---------------------------------------------------------------------------
    def _load_params(self, model: SystemModel, x0: F64) -> tuple[SystemModel, F64, int]:
        current = self.params.current()
        if current is not None:
            version, model, x = current
            applied = self.store.applied()
            if not applied or applied[-1]["version"] != version:  # killed while applying
                self.store.add_applied(self.clock.time(), version, None, "recovered", None)
            return model, x, version
        version = self.params.apply(plain_document(model, x0, "initial parameters"))
        self.store.add_applied(self.clock.time(), version, None, "initial", None)
        return model, x0.copy(), version

    def stop(self) -> None:
        """Ask `run()` to return after the current window (safe from a signal handler)."""
        self._stop.set()
        self._wake.set()

    def run(self) -> None:
        """The service loop; returns after stop() with the robot home and the database closed."""
        try:
            self._start()
            while not self._stop.is_set():
                self._step()
        finally:
            self._shutdown()

    def _start(self) -> None:
        self.bus.emit(
            "started", {"params_version": self.version, "state_dir": str(self.settings.state_dir)}
        )
        try:
            self.watch.poll()
            home = self.measurer.at_home()
        except DeviceError as exc:
            self._fault(exc)
            return
        if not home:
            q = np.round(self.station.robot.joints_deg(), 3).tolist()
            self._enter_fault("robot_not_home", f"robot not at home at start (J = {q} deg)")
            return
        self._set_state(State.IDLE)

    def _shutdown(self) -> None:
        self.recalibrator.close()
        self._set_state(State.STOPPED)
        with contextlib.suppress(Exception):
            self.bus.emit("stopped", {"counters": dict(self.counters)})
        while True:  # nobody will execute what is still queued
            try:
                *_, future = self._commands.get_nowait()
            except Empty:
                break
            future.set_result({"ok": False, "error": "service stopped"})
        self.store.close()

    def _set_state(self, state: State) -> None:
        if state != self.state:
            old, self.state = self.state, state
            if state != State.STOPPED:
                self.bus.emit("state", {"from": old.value, "to": state.value})

    # -- the loop -------------------------------------------------------------------------------
    def _step(self) -> None:
        self._run_commands()
        try:
            self.watch.poll()
        except DeviceError as exc:
            if self.state != State.FAULT:
                self._fault(exc)
            self.clock.wait(self._wake, self.settings.line.poll_s)
            self._wake.clear()
            return
        self._watch_heartbeat()
        self._unshelve()
        if self.state == State.IDLE and not self.paused and self.watch.fresh_window():
            self._window()
            return
        self._between_windows()
        self.clock.wait(self._wake, self.settings.line.poll_s)
        self._wake.clear()

    def _window(self) -> None:
        self._set_state(State.MEASURING)
        n = self.counters["windows"] + 1
        try:
            report = self.cycle.run_window(n)
        except DeviceError as exc:
            self._fault(exc)
            return
        self.counters["windows"] = n
        self.counters["overruns"] += report.overrun
        self.counters["withdrawn"] += bool(report.withdrawn)
        self.bus.emit("window", report.to_json())
        self._set_state(State.PAUSED if self.paused else State.IDLE)
        self._between_windows()

    def _unshelve(self) -> None:
        for alarm_id in self.store.unshelve_expired(self.clock.time()):
            self.bus.emit("alarm_unshelved", {"id": alarm_id}, level=logging.WARNING)

    def _watch_heartbeat(self) -> None:
        alarms = self.store.active_alarms(code="plc_heartbeat")
        if self.watch.lost and not alarms:
            self._alarm("plc_heartbeat", "PLC heartbeat lost: no window is used until it returns")
        elif self.watch.alive and alarms:
            self.store.clear_alarms(self.clock.time(), "plc_heartbeat")
            self.bus.emit("alarm_cleared", {"code": "plc_heartbeat"})

    # -- faults and alarms -------------------------------------------------------------------------
    def _alarm(self, code: str, message: str, priority: str = "high") -> int:
        alarm_id = self.store.raise_alarm(self.clock.time(), code, message, priority)
        self.bus.emit(
            "alarm",
            {"id": alarm_id, "code": code, "message": message, "priority": priority},
            level=logging.WARNING,
        )
        return alarm_id

    def _fault(self, exc: BaseException) -> None:
        self._fault_family = self.note_device_error(exc)
        self._enter_fault("device_fault", f"{type(exc).__name__}: {exc}")

    def _enter_fault(self, code: str, message: str) -> None:
        """FAULT: stop the robot, set the PLC fault bit, raise the alarm (each best effort)."""
        self._set_state(State.FAULT)
        with contextlib.suppress(Exception):
            self.station.robot.abort()
        with contextlib.suppress(Exception):
            self.station.plc.set_signals(busy=False, done=False, fault=True)
        self._alarm(code, message, "urgent")

    # -- measurements --------------------------------------------------------------------------
    def _position(self) -> int:
        return self.store.schedule_position()[0]

    def _record(self, slot: Slot, window: int, reading: Reading | None, reason: str) -> int:
        e = None
        if reading is not None:
            p = self.spheres[slot.target]
            e = residual_mm(self.model, self.x, slot.q_deg, reading.c_sensor_mm, p)
        row = {
            "t": self.clock.time(),
            "window": window,
            "slot": slot.index,
            "target": slot.target,
            "q_deg": slot.q_deg.tolist(),
            "c_sensor_mm": None if reading is None else reading.c_sensor_mm.tolist(),
            "status": "ok" if reading is not None else "rejected",
            "reason": reason,
            "quality": {} if reading is None else reading.quality,
            "params_version": self.version,
            "residual_mm": e,
            "next_position": (slot.index + 1) % len(self.schedule),
        }
        row_id = self.store.add_measurement(row)
        if reading is not None and e is not None:
            self.sweeps.keep(row_id, reading)
            self.new_since_recal += 1
            self._drift(slot.target, e, row_id)
        self.bus.emit(
            "measurement",
            {
                "id": row_id,
                "target": slot.target,
                "slot": slot.index,
                "status": row["status"],
                "residual_mm": e,
                "reason": reason,
            },
        )
        return row_id

    def _drift(self, target: str, e_mm: float, row_id: int) -> None:
        for sig in self.drift.update(target, e_mm):
            if self.drift_onset_id is None:
                self.drift_onset_id = row_id
            self._alarm(
                "drift",
                f"drift of {'all spheres' if sig.stream == '*' else sig.stream}"
                f" ({sig.chart} {sig.value_mm:.3f} > {sig.limit_mm:.3f} mm):"
                " recalibration brought forward",
                "medium",
            )

    # -- recalibration -------------------------------------------------------------------------
    def _between_windows(self) -> None:
        outcome = self.recalibrator.poll()
        if outcome is not None:
            self._recal_done(outcome)
        if self.state in (State.IDLE, State.PAUSED):
            self._maybe_recalibrate()

    def _recal_due(self) -> bool:
        r = self.settings.recalib
        if self.force_recal or self.new_since_recal >= r.every_n:
            return True
        return self.drift_onset_id is not None and self.new_since_recal >= r.holdout_size

    def _maybe_recalibrate(self) -> None:
        if self.recalibrator.busy or self.pending_calibration is not None or not self._recal_due():
            return
        since = 0 if self.drift_onset_id is None else self.drift_onset_id - 1
        r = self.settings.recalib
        rows = self.store.measurements(
            status="ok", since_id=since, last=r.rolling_size + r.holdout_size
        )
        chosen = select_rolling(rows, len(self.schedule), self.schedule.targets, r)
        if chosen is None:
            return
        train, holdout = chosen
        job = RecalJob(
            self.model,
            self.x.copy(),
            as_measurements(train, self.spheres),
            as_measurements(holdout, self.spheres),
            self.settings.gates,
            r.max_nfev,
            int(train[0]["id"]),
            int(holdout[-1]["id"]),
        )
        self.recalibrator.submit(job)
        self.force_recal, self.new_since_recal = False, 0
        self.bus.emit(
            "recalibration_started",
            {"n": len(train), "first_id": job.first_id, "last_id": job.last_id},
        )

    def _recal_done(self, out: RecalOutcome) -> None:
        status = "pending" if out.passed else "rejected"
        cal_id = self.store.add_calibration(
            {
                "t": self.clock.time(),
                "status": status,
                "n_measurements": out.n_measurements,
                "first_id": out.first_id,
                "last_id": out.last_id,
                "rms_mm": out.rms_mm,
                "holdout_rms_mm": out.holdout_rms_mm,
                "current_holdout_rms_mm": out.current_holdout_rms_mm,
                "gates": list(out.failures),
                "reason": "; ".join(out.failures) or "all gates passed",
                "document": out.document,
            }
        )
        self.bus.emit(
            "calibration",
            {
                "id": cal_id,
                "status": status,
                "rms_mm": out.rms_mm,
                "holdout_rms_mm": out.holdout_rms_mm,
                "current_holdout_rms_mm": out.current_holdout_rms_mm,
                "failures": list(out.failures),
            },
        )
        if not out.passed:
            return
        if self.settings.recalib.mode == "auto":
            self._apply_calibration(cal_id, None, "auto")
        else:
            self.pending_calibration = cal_id

    def _apply_calibration(self, cal_id: int, uid: int | None, source: str) -> int:
        cal = next(c for c in self.store.calibrations() if c["id"] == cal_id)
        version = self.params.apply(cal["document"])
        t = self.clock.time()
        self.store.decide_calibration(cal_id, "applied", t, uid, version)
        self._in_force(version, cal_id, source, uid)
        return version

    def _in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None:
        """Parameters `version` are current: reload them, restart the drift charts."""
        current = self.params.current()
        assert current is not None
        self.version, self.model, self.x = current
        self.store.add_applied(self.clock.time(), version, cal_id, source, uid)
        self.pending_calibration = None
        self.drift.reset()
        self.drift_onset_id = None
        self.store.clear_alarms(self.clock.time(), "drift")
        self.bus.emit(
            "parameters_applied",
            {"version": version, "calibration_id": cal_id, "source": source, "uid": uid},
        )
