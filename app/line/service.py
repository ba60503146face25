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
from collections.abc import Mapping, Sequence
from concurrent.futures import Future
from enum import StrEnum
from queue import Empty, Queue
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.line.clock import Clock, RealClock
from app.line.cycle import Cycle, WindowWatch
from app.line.drift import DriftMonitor, prediction_inflation, residual_mm
from app.line.events import EventBus
from app.line.inline_seq import InlineSequential, SequentialCandidate
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
        self.drift = DriftMonitor(s.drift, residual_baseline_n=len(schedule))
        self.recalibrator = recalibrator or Recalibrator()
        self.sequential: InlineSequential | None = None
        if s.recalib.estimator == "sequential":
            self.sequential = InlineSequential(s.recalib, s.gates, self.spheres, len(schedule))
            self.sequential.restart(self.model, self.x, self.params.current_document())
        self.watch = WindowWatch(station.plc, self.clock, s.line)
        self.measurer = SphereMeasurer(station.robot, sensor, s.line)
        self.cycle = Cycle(self.watch, self.measurer, schedule, self._position, self._record)
        if self.sequential is not None and s.recalib.schedule == "adaptive":
            self.cycle.choose = self._most_informative
        self.state = State.STARTING
        self.paused = False
        self.counters = {"windows": 0, "overruns": 0, "withdrawn": 0}
        self.pending_calibration: int | None = None
        self.drift_onset_id: int | None = None  # first measurement after a flagged step
        self.drift_due = False  # the residual charts signalled: recalibrate soon
        self.last_visit: dict[int, tuple[F64, F64]] = {}  # slot -> (q_deg, c_sensor_mm)
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
        self._restore_drift()
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
    def _visited_views(self) -> tuple[F64, F64]:
        """The schedule's configurations measured so far (K, 6) and their last centres (K, 3)."""
        visits = list(self.last_visit.values())
        q = np.array([q for q, _ in visits]).reshape(-1, 6)
        return q, np.array([c for _, c in visits]).reshape(-1, 3)

    def _most_informative(self, slots: Sequence[Slot]) -> Slot:
        assert self.sequential is not None
        return self.sequential.most_informative(self.model, slots, self.last_visit)

    @property
    def cell_temp_c(self) -> float | None:
        """The cell temperature [degC] from the PLC's last reading (None: no sensor)."""
        inputs = self.watch.inputs
        return None if inputs is None else inputs.temp_c

    def _position(self) -> int:
        return self.store.schedule_position()[0]

    def _record(self, slot: Slot, window: int, reading: Reading | None, reason: str) -> int:
        e = None
        temp_c = self.cell_temp_c
        if reading is not None:
            p = self.spheres[slot.target]
            e = residual_mm(self.model, self.x, slot.q_deg, reading.c_sensor_mm, p, temp_c)
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
            "temp_c": temp_c,
            "next_position": (slot.index + 1) % len(self.schedule),
        }
        row_id = self.store.add_measurement(row)
        if reading is not None and e is not None:
            self.sweeps.keep(row_id, reading)
            self.new_since_recal += 1
            self._drift(slot.target, e, self._change_mm(slot, reading.c_sensor_mm), row_id)
            if self.sequential is not None:
                self.sequential.offer({**row, "id": row_id})
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

    def _change_mm(self, slot: Slot, c_sensor_mm: F64) -> float | None:
        """How far the centre moved since this slot's previous visit (same configuration)."""
        prev = self.last_visit.get(slot.index)
        self.last_visit[slot.index] = (slot.q_deg.copy(), np.asarray(c_sensor_mm, float).copy())
        if prev is None or not np.allclose(prev[0], slot.q_deg, atol=1e-6):
            return None
        return float(np.linalg.norm(np.asarray(c_sensor_mm, float) - prev[1]))

    def _drift(self, target: str, e_mm: float, change_mm: float | None, row_id: int) -> None:
        """A residual signal while the change charts watch is slow drift: the service handles
        it (recalibration brought forward), an advisory `drift` alarm of low priority. A step
        (a change signal, or any signal before the change charts watch) may need a person to
        look at the cell: a `drift_step` alarm of high priority, and only measurements from the
        change point on are used."""
        for sig in self.drift.update(target, e_mm, row_id, change_mm):
            where = "all spheres" if sig.stream == "*" else sig.stream
            stat = f"{sig.chart} {sig.value_mm:.3f} > {sig.limit_mm:.3f} mm"
            if sig.family == "residual" and self.drift.change_watching:
                self.drift_due = True
                self._alarm(
                    "drift",
                    f"drift of {where} (residual, {stat}): recalibration brought forward",
                    "low",
                )
                continue
            if self.drift_onset_id is None:
                self.drift_onset_id = sig.onset_ref
                if self.sequential is not None:
                    self.sequential.widen(sig.onset_ref)
            what = "residual" if sig.family == "residual" else "change since the last visit"
            self._alarm(
                "drift_step",
                f"step of {where} ({what}, {stat}) since measurement {self.drift_onset_id}:"
                " check the cell (sensor mount, spheres); recalibrating on the measurements"
                " after it",
                "high",
            )

    def _drift_seed(self, cal: dict[str, Any] | None) -> list[tuple[str, float]]:
        """Residuals of the parameters in force on recent good measurements: the rolling set of
        batch calibration `cal` (its training rows scaled to prediction errors), else the
        last schedule cycle and hold-out."""
        n_train, scale = 0, 1.0
        if cal is not None and cal["first_id"] is not None and not _sequential(cal["document"]):
            rows = self.store.measurements(since_id=int(cal["first_id"]) - 1)
            rows = [r for r in rows if r["id"] <= int(cal["last_id"])]
            n_train = int(cal["n_measurements"])
            scale = prediction_inflation(3 * n_train, len(self.x))
        else:
            r = self.settings.recalib
            rows = self.store.measurements(last=len(self.schedule) + r.holdout_size)
        if len(rows) < len(self.schedule):
            return []
        return [
            (
                str(r["target"]),
                (scale if k < n_train else 1.0)
                * residual_mm(
                    self.model,
                    self.x,
                    r["q_deg"],
                    r["c_sensor_mm"],
                    self.spheres[r["target"]],
                    r.get("temp_c"),
                ),
            )
            for k, r in enumerate(rows)
        ]

    def _restore_drift(self) -> None:
        """After a restart: the residual charts from the stored measurements, the last visits."""
        applied = self.store.applied()
        cal_id = applied[-1]["calibration_id"] if applied else None
        self.drift.reset(self._drift_seed(self.store.calibration(cal_id)))
        for r in self.store.measurements(last=2 * len(self.schedule)):
            if 0 <= r["slot"] < len(self.schedule):
                q = np.asarray(r["q_deg"], float)
                self.last_visit[int(r["slot"])] = (q, np.asarray(r["c_sensor_mm"], float))

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
        flagged = self.drift_onset_id is not None or self.drift_due
        return flagged and self.new_since_recal >= r.holdout_size

    def _maybe_recalibrate(self) -> None:
        if self.sequential is not None:
            if self.pending_calibration is None and self.sequential.due(self._visited_views):
                self._recal_done(self.sequential.candidate(self.model, self.x))
            return
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

    def _recal_done(self, out: RecalOutcome | SequentialCandidate) -> None:
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
        cal = self.store.calibration(cal_id)
        assert cal is not None, f"no calibration {cal_id}"
        version = self.params.apply(cal["document"])
        t = self.clock.time()
        self.store.decide_calibration(cal_id, "applied", t, uid, version)
        self._in_force(version, cal_id, source, uid)
        return version

    def _in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None:
        """Parameters `version` are current: reload them, restart the drift charts (seeded with
        the new parameters' residuals); the drift alarm and onset are cleared when the
        calibration was trained on measurements after the onset only."""
        current = self.params.current()
        assert current is not None
        self.version, self.model, self.x = current
        self.store.add_applied(self.clock.time(), version, cal_id, source, uid)
        self.pending_calibration = None
        cal = self.store.calibration(cal_id)
        if cal is not None and _sequential(cal["document"]):
            # the filter's residuals on the rows it was fed are optimistic by an unknown factor:
            # keep the baselines (measured: reseeding gave 21 low alarms in 4 h)
            self.drift.restart()
        else:
            self.drift.reset(self._drift_seed(cal))
        if self.sequential is not None and (cal is None or not _sequential(cal["document"])):
            self.sequential.restart(self.model, self.x, self.params.current_document())
        onset, self.drift_due = self.drift_onset_id, False
        self.store.clear_alarms(self.clock.time(), "drift")
        if onset is None or (cal is not None and int(cal["first_id"] or 0) >= onset):
            self.drift_onset_id = None  # trained after the step (else the next one will be)
            self.store.clear_alarms(self.clock.time(), "drift_step")
        self.bus.emit(
            "parameters_applied",
            {"version": version, "calibration_id": cal_id, "source": source, "uid": uid},
        )


def _sequential(document: Mapping[str, Any] | None) -> bool:
    """The calibration came from the sequential estimator (app.line.inline_seq)."""
    return bool(document) and (document or {}).get("estimator", {}).get("kind") == "sequential"
