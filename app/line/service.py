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

Operations (DESIGN.md section 6): what the decisions depend on (progress towards the next
calibration, the drift charts with their baselines and change point, the calibration in
flight, pause, counters, the last visit of every slot) is one snapshot in the database, written
in the transaction of the measurement, apply or command that changed it, and restored at start:
a restarted service carries on as if it had never stopped (a calibration killed in flight runs
again on the same measurements; one killed in its apply is completed). `params/current.json` is
derived: damaged or missing, it is rebuilt from the history version the database says is in
force. A storage failure (disk full, I/O error) is a fault like a device's: FAULT with a
`state_storage` alarm (kept in memory until it can be stored), nothing acknowledged that was not
committed, the service keeps answering; `reset` once the storage writes again. An unexpected
exception in the loop, a connection thread or the identification worker is logged with its
traceback, alarmed (`internal_error`), puts the cell in FAULT, and `run()` returns with
`exit_code` 1 so that the supervisor restarts the process; a restarted service finds the urgent
alarm and stays in FAULT until an operator resets it.

A device that cannot be reached at start (`Station.open(defer_unreachable=True)`: its URL is
right, nothing answers) does not end the process: the service starts in FAULT with a
`device_unreachable` alarm naming the device, answers its socket and OPC UA, and tries to open
it again after 1, 2, 5, 10, then every 30 s of its clock (`DEVICE_RETRY_S`). Nothing has moved,
so once every device is open the alarm clears by itself and the start goes on as usual (a fault
alarm held from before still waits for a reset; a robot away from home is `robot_not_home`).

A step (a knock) flagged by the drift charts opens a suspect interval and is attributed to the
rigid group that moved after every window, with a fast correction of that group (StepHandler,
app/line/step_handler.py; the numbers in app/line/step.py and calib/attribution.py); until it
is corrected the windows measure the slots that serve the attribution (`_choose`,
`_slots_wanted`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.errors import InputError
from app.formats.params import plain_document
from app.line.accuracy import (
    ACCURACY_GROUP,
    VOUCHED,
    Accuracy,
    document_seed,
    evidence,
    statement,
    with_prediction,
)
from app.line.cycle import Cycle, WindowWatch
from app.line.drift import DriftMonitor, prediction_inflation, residual_mm
from app.line.events import EventBus
from app.line.inline_seq import InlineSequential, SequentialCandidate
from app.line.measure import Reading, SphereMeasurer, SphereSensor
from app.line.operator import Operator
from app.line.params_store import ParamsStore, first_in_force
from app.line.recalib import Recalibrator, RecalJob, RecalOutcome, as_measurements, select_rolling
from app.line.roles import Roles
from app.line.schedule import Schedule, Slot
from app.line.sensor_watch import SensorWatch
from app.line.settings import ServiceSettings
from app.line.statedir import StateDir
from app.line.states import FAULT_CODES, AlarmCode, State, suspect_json, utc_text
from app.line.station import Station
from app.line.status import alarm_event, device_of, status_reply
from app.line.step import Step, StepStatus, step_alarm_text
from app.line.step_fit import MIN_STEP_REFS, StepCorrection, step_slot
from app.line.step_handler import StepHandler
from app.line.store import StorageError, Store
from app.line.sweeps import SweepArchive
from calib.attribution import NONE, SEVERAL, step_groups
from calib.compliance import CompliantModel
from calib.model import SystemModel
from drivers.clock import Clock, RealClock
from drivers.errors import DeviceError

F64 = NDArray[np.float64]
SPACE_CHECK_S = 60.0  # how often the free space under the state directory is looked at
RETENTION_S = 3600.0  # how often events past [service] events_keep_days are deleted
#: the waits [s] between attempts to open a device unreachable at start (then the last, again)
DEVICE_RETRY_S = (1.0, 2.0, 5.0, 10.0, 30.0)
#: a schedule's view rejected this many times in a row is left out of the windows (`_seen`)
VIEW_LOST_TRIES = 3


class Service:
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
        initial_residuals: Mapping[str, Any] | None = None,
    ) -> None:
        """`initial_residuals`: the identification residuals of `x_initial` (n_measurements,
        rms_mm, n_parameters) and, when its commissioning validated it across the workspace,
        `validation_errors_mm` (the norms), written into a new directory's first version (its
        U95 seed, app.line.accuracy.document_seed)."""
        self.settings = s = settings or ServiceSettings()
        self._initial_residuals = initial_residuals
        self.clock = clock or RealClock()
        self.station, self.schedule = station, schedule
        self.spheres = {k: np.asarray(v, dtype=np.float64) for k, v in spheres_part_mm.items()}
        s.state_dir.mkdir(parents=True, exist_ok=True)
        self.paths = StateDir(s.state_dir)
        self.roles = Roles.of(s.ops.engineers_group)  # who may approve, reset, ... (or exit 2)
        self.store = Store(self.paths.db)
        self.params = ParamsStore(s.state_dir)
        self.params.remove_stale()  # the service alone cleans (read-only callers never do)
        self.sweeps = SweepArchive(self.paths.sweeps, s.ops.raw_sweeps_keep)
        self.bus = EventBus(self.store, self.clock)
        self._start_alarms: list[tuple[str, str, str]] = []  # raised once the loop runs
        self._recovered: tuple[int, int | None] | None = None  # an apply to complete
        self.service_model = model  # [service] model: what it identifies
        try:
            self.model, self.x, self.version = self._load_params(
                model, np.asarray(x_initial, float)
            )
        except BaseException:
            self.store.close()
            raise
        self.drift = DriftMonitor(s.drift, residual_baseline_n=len(schedule))
        d = s.drift
        self.sensor_watch = SensorWatch(s.max_ps_mm, d.ewma_lambda, d.cusum_h, d.baseline_n)
        self.sensor_watch.replay([r["quality"] for r in self.store.measurements(last=500)])
        self.recalibrator = recalibrator or Recalibrator()
        self.sequential: InlineSequential | None = None
        if s.recalib.estimator == "sequential":
            self.sequential = InlineSequential(s.recalib, s.gates, self.spheres, len(schedule))
            self.sequential.restart(self.model, self.x, self.params.current_document())
        self.watch = WindowWatch(station.plc, self.clock, s.line)
        self.measurer = SphereMeasurer(station.robot, sensor, s.line)
        self.cycle = Cycle(
            self.watch,
            self.measurer,
            schedule,
            self._position,
            self._record,
            choose=self._choose,
            slots_wanted=self._slots_wanted,
        )
        self.state = State.STARTING
        self.paused = False
        self.counters = {"windows": 0, "overruns": 0, "withdrawn": 0}
        self.pending_calibration: int | None = None
        # a rollback in auto mode: automatic applies held until an engineer's resume or
        # approve ({"version", "uid", "since_utc"}; None: not held)
        self.auto_hold: dict[str, Any] | None = None
        self.drift_onset_id: int | None = None  # first measurement after a flagged step
        self.drift_due = False  # the residual charts signalled: recalibrate soon
        self._views_lost: set[int] = set()  # slots left out by `_seen`, alarmed
        self.last_visit: dict[int, tuple[F64, F64]] = {}  # slot -> (q_deg, c_sensor_mm)
        self.visit_ids: dict[int, int] = {}  # slot -> the measurement id of its last visit
        self.change_from_id = 0  # a change from a visit before this id spans a known step
        self.step: Step | None = None  # a flagged step: attribution, correction (app.line.step)
        # what the cell states about its accuracy (app.line.accuracy): the version in force's
        # seed residuals, the statement after the last window, an open accuracy interval
        self.u_seed: list[float] = []
        self.accuracy: Accuracy | None = None
        self.accuracy_suspect_id: int | None = None
        self.new_since_recal = 0
        self.force_recal = False
        self._skipped: tuple[int, int] | None = None  # the set a recalibration was skipped on
        self.recal_ids: dict[str, list[int]] | None = None  # the calibration in flight
        # good measurements recorded by this process, and the (count, since) at which the
        # rolling set was last found incomplete: not looked for again until one more comes
        self._good_rows = 0
        self._incomplete: tuple[int, int] | None = None
        self.exit_code = 0  # 1 after an internal error: the supervisor restarts the process
        self._crash: BaseException | None = None  # from another thread (crash())
        self.unstored_alarms: list[dict[str, Any]] = []  # raised while the storage failed
        self.storage_failed = False  # until a reset finds it writing again
        self._space_check_t = self._retention_t = -np.inf
        self._temperature_bad: bool | None = None  # known after the first poll
        self._stop = threading.Event()
        self.wake = threading.Event()
        self.device_errors: dict[str, dict[str, str]] = {}  # family -> {"error", "utc"}
        self.fault_family: str | None = None  # the device of the fault in force (None: unknown)
        # while a device unreachable at start is retried: {"attempts", "next_utc", "wait_s"}
        self.device_retry: dict[str, Any] | None = None
        # called in the loop's thread after each window and what follows it between windows
        # (the simulated line holds the service there, its virtual time standing, to look)
        self.after_window: Callable[[], None] | None = None
        self.operator = Operator(self)  # the operator's commands (app.line.operator)
        self.step_handler = StepHandler(self)  # a flagged step's handling (app.line.step_handler)
        self.log = logging.getLogger("rvis.line")
        self.restore()
        if self._recovered is not None:  # an apply the database does not know yet
            self.in_force(*self._recovered, "recovered", None)

    # -- life cycle ---------------------------------------------------------------------------
    def _load_params(self, model: SystemModel, x0: F64) -> tuple[SystemModel, F64, int]:
        """The parameters in force: `params/current.json` as the database's applied version
        (rebuilt from the history when damaged or missing; an apply the database does not
        know yet is completed at start), or x0 applied as the initial version."""
        applied = self.store.applied()
        last = int(applied[-1]["version"]) if applied else None
        try:
            current = self.current_params()
            damage = "missing" if current is None else ""
        except (InputError, OSError, ValueError, KeyError, TypeError) as exc:
            current, damage = None, f"damaged ({exc})"
        if current is None and last is None:  # a new state directory
            if isinstance(model, CompliantModel):
                # a rigid commissioning's vector, its temperature unknown here (the reference
                # temperature's; `rvis run --params` carries a file at its own)
                x0 = model.carried(x0)
            doc = plain_document(model, x0, "initial parameters")
            if self._initial_residuals is not None:
                given = dict(self._initial_residuals)
                validation = given.pop("validation_errors_mm", None)
                doc |= {"residuals": given, "n_parameters": given.get("n_parameters")}
                if validation:  # the commissioning's workspace validation (app.line.accuracy)
                    doc["validation"] = {"errors_mm": [float(e) for e in validation]}
            version = first_in_force(self.params, self.store, doc, "initial", self.clock)
            return model, x0.copy(), version
        if current is None:
            assert last is not None
            current = self._rebuild_current(last, damage)
        version, model, x = current
        if version != last:  # killed while applying: complete it at start
            doc = self.params.current_document() or {}
            cal_id = doc.get("calibration_id")
            self._recovered = (version, cal_id if isinstance(cal_id, int) else None)
        return model, x, version

    def current_params(self) -> tuple[int, SystemModel, F64] | None:
        """(version, model, x) in force (params.current()), as the service identifies them: a
        rigid version (a rigid commissioning) carried into a compliant [service] model at its
        calibration temperature (calib.compliance.carry)."""
        return self.params.current(self.service_model)

    def _rebuild_current(self, version: int, damage: str) -> tuple[int, SystemModel, F64]:
        path = self.params.current_path
        try:
            self.params.rollback(version)
            current = self.current_params()
        except (InputError, OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(
                f"{damage}, and history version {version} (in force by the database) cannot"
                f" rebuild it: {exc}",
                file=path,
            ) from exc
        assert current is not None
        self._start_alarms.append(
            (
                AlarmCode.PARAMS_REBUILT,
                f"{path} was {damage}: rebuilt from history {version}",
                "high",
            )
        )
        return current

    # -- the decision state (store.save_state) -------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        return {
            "params_version": self.version,
            "last_measurement_id": self.store.last_measurement_id(),
            "paused": self.paused,
            "auto_hold": self.auto_hold,
            "force_recal": self.force_recal,
            "new_since_recal": self.new_since_recal,
            "drift_onset_id": self.drift_onset_id,
            "drift_due": self.drift_due,
            "counters": dict(self.counters),
            "recal_ids": self.recal_ids,
            "last_visit": {
                str(k): [q.tolist(), c.tolist()] for k, (q, c) in self.last_visit.items()
            },
            "visit_ids": {str(k): v for k, v in self.visit_ids.items()},
            "change_from_id": self.change_from_id,
            "step": None if self.step is None else self.step.to_json(),
            "drift": self.drift.to_json(),
            "sequential_step": None if self.sequential is None else self.sequential.step_json(),
            "u_seed": self.u_seed,
            "accuracy_suspect_id": self.accuracy_suspect_id,
            "accuracy": None if self.accuracy is None else self.accuracy.to_json(),
        }

    def save_state(self) -> None:
        self.store.save_state(self.clock.time(), self.snapshot())

    def restore(self) -> None:
        """The decision state from the database (at start, and after a storage fault)."""
        doc = self.store.load_state()
        if doc is None:  # a state directory of an older rvis: what the rows tell
            self._restore_drift()
            return
        self.paused = bool(doc["paused"])
        self.auto_hold = doc.get("auto_hold")  # a state saved before the hold: not held
        self.force_recal = bool(doc["force_recal"])
        self.new_since_recal = int(doc["new_since_recal"])
        self.drift_onset_id, self.drift_due = doc["drift_onset_id"], bool(doc["drift_due"])
        self.counters.update({k: int(v) for k, v in doc["counters"].items()})
        self.recal_ids = doc["recal_ids"]
        self.last_visit = {
            int(k): (np.asarray(q, float), np.asarray(c, float))
            for k, (q, c) in doc["last_visit"].items()
        }
        self.visit_ids = {int(k): int(v) for k, v in doc.get("visit_ids", {}).items()}
        self.change_from_id = int(doc.get("change_from_id", 0))
        self.step = Step.from_json(doc.get("step"))
        self.drift.load_json(doc["drift"])
        if self.sequential is not None:
            self.sequential.load_step_json(doc.get("sequential_step"))
        # a state saved before the accuracy statement: the seed of the version in force
        seed = doc.get("u_seed")
        self.u_seed = [float(e) for e in seed] if seed is not None else self._version_seed()
        self.accuracy_suspect_id = doc.get("accuracy_suspect_id")
        acc = doc.get("accuracy")
        if acc is not None:
            self.accuracy = Accuracy(
                acc["u95_mm"], int(acc["n"]), str(acc["basis"]), float(acc["limit_mm"])
            )

    def stop(self) -> None:
        """Ask `run()` to return after the current window (safe from a signal handler)."""
        self._stop.set()
        self.wake.set()

    def crash(self, exc: BaseException) -> None:
        """An unexpected error in another thread of the service: the loop ends as for its own
        (safe from any thread)."""
        self._crash = exc
        self.wake.set()

    def request(
        self,
        cmd: str,
        args: dict[str, Any] | None = None,
        uid: int | None = None,
        groups: tuple[int, ...] | None = None,
    ) -> Future[dict[str, Any]]:
        """An operator's command (app.line.operator) from the peer `uid` in `groups` (None:
        from the group database; uid None: this process); the future's result is the reply."""
        return self.operator.request(cmd, args, uid, groups)

    def status(self) -> dict[str, Any]:
        """The status reply (app.line.status), from any thread."""
        return status_reply(self)

    def note_device_error(self, exc: BaseException) -> str | None:
        """Keep `exc` as the last error of the device it came from (the status reply's
        `devices`); returns that device's family (None: not attributable to one)."""
        family = device_of(exc, self.station.devices())
        if family is not None:
            self.device_errors[family] = {
                "error": f"{type(exc).__name__}: {exc}",
                "utc": utc_text(self.clock.time()),
            }
        return family

    def run(self) -> None:
        """The service loop; returns after stop() with the robot home and the database closed,
        or after an internal error with the cell in FAULT and `exit_code` 1."""
        try:
            self._start()
            while not self._stop.is_set():
                self._step()
        except Exception as exc:
            self._crashed(exc)
        finally:
            self._shutdown()

    def _crashed(self, exc: BaseException) -> None:
        self.exit_code = 1
        text = f"{type(exc).__name__}: {exc}"
        self.log.error(
            "internal error: %s",
            text,
            exc_info=exc,
            extra={"event": "internal_error", "data": {"error": text}},
        )
        with contextlib.suppress(Exception):
            self._enter_fault(
                AlarmCode.INTERNAL_ERROR,
                f"internal error ({text}): the service stops to be restarted",
            )

    def _start(self) -> None:
        self.bus.emit(
            "started", {"params_version": self.version, "state_dir": str(self.settings.state_dir)}
        )
        for code, message, priority in self._start_alarms:
            self.alarm(code, message, priority)
        self.pending_calibration = self.store.pending_calibration()
        if self.pending_calibration is not None and self.applies_automatically():
            self.apply_calibration(self.pending_calibration, None, "auto")  # killed before
        self._resubmit()
        self._check_space()
        if not self._await_devices():
            return  # stopped while waiting for a device
        held = [a for a in self.store.active_alarms() if a["code"] in FAULT_CODES]
        if held:
            self._hold_fault(held[0])
            return
        try:
            self.watch.poll()
            home = self.measurer.at_home()
        except DeviceError as exc:
            self._fault(exc)
            return
        if not home:
            q = np.round(self.station.robot.joints_deg(), 3).tolist()
            self._enter_fault(AlarmCode.ROBOT_NOT_HOME, f"robot not at home at start (J = {q} deg)")
            return
        self.set_state(State.PAUSED if self.paused else State.IDLE)

    def _await_devices(self) -> bool:
        """Every device open (module docstring): at once, or after retries with back-off in
        FAULT with a `device_unreachable` alarm, the operator's commands answered meanwhile;
        False when stopped first."""
        stale = self.store.active_alarms(code=AlarmCode.DEVICE_UNREACHABLE)  # from a killed process
        if not self.station.unreachable:
            self._clear_unreachable(bool(stale), None)
            return True
        if stale:
            self.clear_alarms(AlarmCode.DEVICE_UNREACHABLE)
        errors = dict(self.station.unreachable)
        for exc in errors.values():
            self.note_device_error(exc)
        self.fault_family = next(iter(errors))
        self._enter_fault(AlarmCode.DEVICE_UNREACHABLE, self._unreachable_text(errors))
        attempts = 0
        while True:
            wait_s = DEVICE_RETRY_S[min(attempts, len(DEVICE_RETRY_S) - 1)]
            due = self.clock.monotonic() + wait_s
            self.device_retry = {
                "attempts": attempts,
                "wait_s": wait_s,
                "next_utc": utc_text(self.clock.time() + wait_s),
            }
            while (left := due - self.clock.monotonic()) > 0 and not self._stop.is_set():
                self.clock.wait(self.wake, left)
                self.wake.clear()
                if self._crash is not None:
                    raise self._crash
                self.operator.run_commands()
            if self._stop.is_set():
                return False
            attempts += 1
            errors = self.station.open_unreachable()
            for exc in errors.values():
                self.note_device_error(exc)
            if not errors:
                self._clear_unreachable(True, attempts)
                return True
            self.fault_family = next(iter(errors))
            unreachable = {f: f"{type(e).__name__}: {e}" for f, e in errors.items()}
            self.bus.emit("device_retry", {"attempts": attempts, "unreachable": unreachable})

    def _unreachable_text(self, errors: Mapping[str, DeviceError]) -> str:
        parts = [
            f"{f} ({self.station.urls.get(f, '')}) unreachable: {type(e).__name__}: {e}"
            for f, e in errors.items()
        ]
        waits = ", ".join(f"{w:g}" for w in DEVICE_RETRY_S[:-1])
        return (
            f"{'; '.join(parts)}; the service tries again after {waits} s, then every"
            f" {DEVICE_RETRY_S[-1]:g} s, and leaves FAULT by itself once every device answers"
        )

    def _clear_unreachable(self, raised: bool, attempts: int | None) -> None:
        """Every device is open: the `device_unreachable` alarm (if any) cleared, the PLC's
        fault bit it set taken back, the fault's device forgotten."""
        self.device_retry = None
        if not raised:
            return
        self.clear_alarms(AlarmCode.DEVICE_UNREACHABLE)
        self.fault_family = None
        with contextlib.suppress(DeviceError):
            self.station.plc.set_signals(busy=False, done=False, fault=False)
        if attempts is not None:
            self.bus.emit("devices_opened", {"attempts": attempts})

    def _hold_fault(self, alarm: dict[str, Any]) -> None:
        """Restarted with a fault alarm in force: stay in FAULT until an operator's reset."""
        self.set_state(State.FAULT)
        with contextlib.suppress(Exception):
            self.station.robot.abort()
        with contextlib.suppress(Exception):
            self.station.plc.set_signals(busy=False, done=False, fault=True)
        self.log.warning(
            "restarted in FAULT: alarm %s in force (%s)", alarm["code"], alarm["message"]
        )

    def _shutdown(self) -> None:
        self.recalibrator.close()
        self.set_state(State.STOPPED)
        with contextlib.suppress(Exception):
            self.bus.emit("stopped", {"counters": dict(self.counters)})
        self.operator.cancel_queued("service stopped")  # nobody will execute them
        self.store.close()

    def set_state(self, state: State) -> None:
        if state != self.state:
            old, self.state = self.state, state
            if state != State.STOPPED:
                self.bus.emit("state", {"from": old.value, "to": state.value})

    # -- the loop -------------------------------------------------------------------------------
    def _step(self) -> None:
        if self._crash is not None:
            raise self._crash
        try:
            self._step_once()
        except StorageError as exc:
            self.storage_fault(exc)
            self._pause_poll()

    def _pause_poll(self) -> None:
        self.clock.wait(self.wake, self.settings.line.poll_s)
        self.wake.clear()

    def _step_once(self) -> None:
        self.operator.run_commands()
        try:
            self.watch.poll()
        except DeviceError as exc:
            if self.state != State.FAULT:
                self._fault(exc)
            self._pause_poll()
            return
        self._watch_heartbeat()
        self._watch_temperature()
        self._store_clamped()
        self._unshelve()
        if self.state == State.IDLE and not self.paused and self.watch.fresh_window():
            self._window()
            return
        self._between_windows()
        self._pause_poll()

    def _window(self) -> None:
        self.set_state(State.MEASURING)
        n = self.counters["windows"] + 1
        t_open = self.clock.time()  # within a poll of the window's rising edge
        try:
            report = self.cycle.run_window(n)
        except DeviceError as exc:
            self._fault(exc)
            return
        self.counters["windows"] = n
        self.counters["overruns"] += report.overrun
        self.counters["withdrawn"] += bool(report.withdrawn)
        self._state_accuracy(t_open)
        self.save_state()
        acc = self.accuracy
        self.bus.emit(
            "window",
            {
                **report.to_json(),
                "t_open": t_open,
                "params_version": self.version,
                "u95_mm": None if acc is None else acc.u95_mm,
                "vouched": acc is not None and acc.vouched,
            },
        )
        self.set_state(State.PAUSED if self.paused else State.IDLE)
        self._between_windows()
        if self.after_window is not None:
            self.after_window()

    def _state_accuracy(self, t_open: float) -> None:
        """After a window: the U95 of a point measured now from the evidence (app.line.accuracy),
        stated for the window's bodies; a window the cell cannot vouch for within the limit
        opens an accuracy suspect interval (from when it opened), the first one vouched for
        again closes it."""
        n_max = len(self.schedule)
        rows = self.store.measurements(last=4 * n_max)
        norms, basis = evidence(rows, self.version, self.drift_onset_id, self.u_seed, n_max)
        acc = statement(norms, basis, self.settings.recalib.accuracy_limit_mm)
        step = self.step  # a fast correction's predicted uncertainty, for its version
        if step is not None and step.predicted_version == self.version:
            acc = with_prediction(acc, norms, step.predicted_sigma_mm, n_max)
        self.accuracy = acc
        with self.store.batch():
            self.store.state_window_u95(acc.u95_mm)
            open_id = self.accuracy_suspect_id
            # (a step's open interval speaks for these windows already)
            if not acc.vouched and open_id is None and not self._suspect_open():
                # from the last measurement before this window (the last one vouched for) on
                before = [r for r in rows if r["t"] < t_open]
                first_id = int(before[-1]["id"]) + 1 if before else self.store.last_measurement_id()
                self.accuracy_suspect_id = sid = self.store.open_suspect(
                    {
                        "t_start": float(before[-1]["t"]) if before else t_open,
                        "last_good_id": int(before[-1]["id"]) if before else None,
                        "onset_id": first_id,
                        "params_version": self.version,
                        "group_name": ACCURACY_GROUP,
                        "text": f"the cell cannot vouch for its accuracy: {acc.text()}",
                    }
                )
                opened = self.store.suspect(sid)
            elif acc.vouched and open_id is not None:
                row = self.store.suspect(open_id) or {}
                self.store.update_suspect(
                    open_id,
                    t_end=t_open,
                    end_reason=VOUCHED,
                    end_version=self.version,
                    text=f"{row.get('text', '')}; vouched for again: {acc.text()}",
                )
                self.accuracy_suspect_id, opened = None, self.store.suspect(open_id)
            else:
                opened = None
        if opened is not None:
            self.bus.emit("suspect_interval", suspect_json(opened))

    def _unshelve(self) -> None:
        t = self.clock.time()
        for alarm_id in self.store.unshelve_expired(t):
            row = self.store.alarm(alarm_id)
            data = {"id": alarm_id} if row is None else alarm_event(row, "raised")
            self.bus.emit("alarm_unshelved", data, level=logging.WARNING, t=t)

    def _watch_heartbeat(self) -> None:
        alarms = self.store.active_alarms(code=AlarmCode.PLC_HEARTBEAT)
        if self.watch.lost and not alarms:
            self.alarm(
                AlarmCode.PLC_HEARTBEAT, "PLC heartbeat lost: no window is used until it returns"
            )
        elif self.watch.alive and alarms:
            self.clear_alarms(AlarmCode.PLC_HEARTBEAT)

    def _watch_temperature(self) -> None:
        """A `temperature` alarm while the PLC should provide the cell temperature and does
        not (raised once, cleared when a plausible value returns, or when the cell file no
        longer reads the word); meanwhile measurements are stored without one and the compliant
        model leaves its thermal term out. The database is asked only when that changes."""
        why = self.watch.temperature()[1]
        if bool(why) == self._temperature_bad:
            return  # nothing changed since the last poll: no query
        active = self.store.active_alarms(code=AlarmCode.TEMPERATURE)
        if why and not active:
            self.alarm(
                AlarmCode.TEMPERATURE,
                f"{why}: no cell temperature; measurements are stored without one and the"
                " thermal term is left out until a plausible value returns",
                "medium",
            )
        elif not why and active:
            self.clear_alarms(AlarmCode.TEMPERATURE)
        self._temperature_bad = bool(why)

    def _store_clamped(self) -> None:
        """The windows the PLC opened since the last poll, each with the body clamped in it
        ([line] plc_body_id; WindowWatch): one row each, taken from the queue once stored (a
        storage failure keeps them until a reset finds it writing again)."""
        clamped = self.watch.clamped
        while clamped and not self.storage_failed:
            self.store.add_window(*clamped[0])
            clamped.popleft()

    # -- faults and alarms -------------------------------------------------------------------------
    def alarm(self, code: str, message: str, priority: str = "high") -> int:
        """Raise an alarm (stored; kept in memory while the storage fails); its id."""
        t = self.clock.time()
        try:
            alarm_id = self.store.raise_alarm(t, code, message, priority)
        except StorageError:
            alarm_id = self._unstored_alarm(code, message, priority)
        self.bus.emit(
            "alarm",
            {
                "id": alarm_id,
                "code": code,
                "message": message,
                "priority": priority,
                "state": "raised",
            },
            level=logging.WARNING,
            t=t,
        )
        return alarm_id

    def clear_alarms(self, code: str, t: float | None = None) -> int:
        """Clear the active alarms of `code` (stored), each an `alarm_cleared` event with its
        id (OPC UA: that occurrence of the condition ends); how many."""
        t = self.clock.time() if t is None else t
        live = self.store.active_alarms(code=code)
        if live:
            self.store.clear_alarms(t, code)
        for a in live:
            self.bus.emit("alarm_cleared", alarm_event(a, "cleared"), t=t)
        return len(live)

    def _unstored_alarm(self, code: str, message: str, priority: str) -> int:
        for a in self.unstored_alarms:
            if a["code"] == code:
                return int(a["id"])
        alarm_id = -(len(self.unstored_alarms) + 1)  # negative: not in the database (yet)
        self.unstored_alarms.append(
            {
                "id": alarm_id,
                "code": code,
                "priority": priority,
                "message": message,
                "state": "raised",
                "t_raised": self.clock.time(),
            }
        )
        return alarm_id

    def storage_fault(self, exc: StorageError) -> None:
        """The state storage failed: FAULT with the robot stopped, nothing acknowledged."""
        if self.state == State.FAULT and self.storage_failed:
            return
        self.storage_failed = True
        free = self.paths.free_mb()
        self.log.error("state storage failed: %s", exc, extra={"event": "state_storage"})
        self._enter_fault(
            AlarmCode.STATE_STORAGE,
            f"state storage failed ({exc}; {free:.0f} MB free under {self.paths.root}): the"
            " measurement was not acknowledged; free space or repair, then reset",
        )

    def _check_space(self) -> None:
        """A `low_disk` alarm while the free space is below [service] min_free_mb."""
        now = self.clock.monotonic()
        if now - self._space_check_t < SPACE_CHECK_S:
            return
        self._space_check_t = now
        free, floor = self.paths.free_mb(), self.settings.ops.min_free_mb
        active = self.store.active_alarms(code=AlarmCode.LOW_DISK)
        if free < floor and not active:
            self.alarm(
                AlarmCode.LOW_DISK,
                f"{free:.0f} MB free under {self.paths.root} (below [service] min_free_mb ="
                f" {floor:g}): free space before the state storage fills",
                "medium",
            )
        elif free >= floor and active:
            self.clear_alarms(AlarmCode.LOW_DISK)

    def _retain(self) -> None:
        """At most once an hour: events older than [service] events_keep_days are deleted (in
        short transactions), and the documents of calibrations rejected more than
        rejected_keep_days ago dropped; the record (measurements, calibrations with their
        figures, applied versions, alarms, the operators' audit) is kept."""
        now = self.clock.monotonic()
        if now - self._retention_t < RETENTION_S:
            return
        self._retention_t = now
        s, t = self.settings.ops, self.clock.time()
        if s.events_keep_days > 0:
            n = self.store.prune_events(t - s.events_keep_days * 86400.0)
            if n:
                self.log.info(
                    "retention: %d events older than %g days deleted", n, s.events_keep_days
                )
        if s.rejected_keep_days > 0:
            n = self.store.prune_rejected_documents(t - s.rejected_keep_days * 86400.0)
            if n:
                self.log.info("retention: documents of %d rejected calibrations dropped", n)

    def _fault(self, exc: BaseException) -> None:
        """FAULT on a device's error; the alarm names the device and its URL when the error
        is one device's (`plc (plc+modbus://...): DeviceConnectionError: ...`)."""
        family = self.fault_family = self.note_device_error(exc)
        where = "" if family is None else f"{family} ({self.station.urls.get(family, '')}): "
        self._enter_fault(AlarmCode.DEVICE_FAULT, f"{where}{type(exc).__name__}: {exc}")

    def _enter_fault(self, code: str, message: str) -> None:
        """FAULT: stop the robot, set the PLC fault bit, raise the alarm (each best effort)."""
        self.set_state(State.FAULT)
        with contextlib.suppress(Exception):
            self.station.robot.abort()
        with contextlib.suppress(Exception):
            self.station.plc.set_signals(busy=False, done=False, fault=True)
        self.alarm(code, message, "urgent")

    # -- measurements --------------------------------------------------------------------------
    def _visited_views(self) -> tuple[F64, F64]:
        """The schedule's configurations measured so far (K, 6) and their last centres (K, 3)."""
        visits = list(self.last_visit.values())
        q = np.array([q for q, _ in visits]).reshape(-1, 6)
        return q, np.array([c for _, c in visits]).reshape(-1, 3)

    def _choose(self, slots: Sequence[Slot]) -> Slot:
        """The next slot among those that fit (in the plan's order from the position): for a
        step being attributed, the one that serves it (app.line.step_fit.step_slot: the most
        informative for the group the last attribution chose, or for all of them); adaptive
        scheduling, the most informative for the sequential estimator; else the next (also
        while a corrected step's post-step measurements are gathered: the whole schedule).
        A view rejected at its last tries is left out while others fit (`_seen`)."""
        slots = self._seen(slots)
        if self._measuring_for_step() and self.step is not None:
            if self.step.status in (StepStatus.CORRECTED, StepStatus.SEVERAL):
                return slots[0]  # the full recalibration's set: the whole schedule
            if self.step.status == StepStatus.FOLLOWING and self.sequential is not None:
                # the filter's candidate waits for its predicted uncertainty at every view of
                # the schedule: the slot that lowers it most (measured: the step's own slots
                # left it at 0.033 mm, above seq_max_std_mm, for the rest of an 8 h shift)
                return self.sequential.most_informative(self.model, slots, self.last_visit)
            onset = self.step.onset_id
            after = self.store.measurements(since_id=onset - 1)
            before = self.store.measurements(before_id=onset, last=len(self.schedule))
            if len(after) >= len(self.schedule) > len(before):
                # a new cell (fewer references than slots): a schedule's worth measured for
                # the attribution and no decision yet, the full recalibration's set next
                return slots[0]
            recent = [int(r["slot"]) for r in reversed(before)]
            lead = [g for g in step_groups(self.model) if g.name == self.step.choice]
            groups = lead if lead and lead[0].name not in (NONE, SEVERAL) else None
            return step_slot(
                self.model,
                self.x,
                slots,
                after,
                recent,
                self.last_visit,
                groups,
                self.step_handler.volume_views(),
            )
        if self.sequential is not None and self.settings.recalib.schedule == "adaptive":
            return self.sequential.most_informative(self.model, slots, self.last_visit)
        return slots[0]

    def _seen(self, slots: Sequence[Slot]) -> Sequence[Slot]:
        """The slots not rejected VIEW_LOST_TRIES times in a row since their last good
        measurement (all of them when none is left): a view whose sphere left the sensor's
        measuring volume (a knock moved the mount or the spheres by more than the plan's
        margin) is rejected at every try, and tried again and again it takes every slot of a
        step's windows (measured: 404 rejected of 430 in a shift, the step never decided). The
        first time a view is left out a `view_lost` alarm names it and what fixes it."""
        lost = self._lost_views()
        if not lost:
            return slots
        new = sorted(set(lost) - self._views_lost)
        if new:
            self._views_lost |= set(new)
            names = ", ".join(f"{i} ({self.schedule.slots[i].target})" for i in new)
            self.alarm(
                AlarmCode.VIEW_LOST,
                f"schedule slot {names} rejected {VIEW_LOST_TRIES} times in a row: left out of"
                " the windows; the sphere is no longer where the plan saw it (a knock, a moved"
                " sphere): re-plan with `rvis plan` and restart, or commission again",
                "low",
            )
        return [s for s in slots if s.index not in lost] or slots

    def _lost_views(self) -> set[int]:
        """The schedule's slots rejected VIEW_LOST_TRIES times in a row (`_seen`)."""
        return set(self.store.rejected_in_a_row(VIEW_LOST_TRIES))

    def _slots_wanted(self) -> int:
        """Slots this window may measure: more while a step is attributed (as many as fit)."""
        line = self.settings.line
        if self._measuring_for_step():
            return max(line.slots_per_window, line.step_slots_per_window)
        return line.slots_per_window

    def _measuring_for_step(self) -> bool:
        """The windows measure for a flagged step (more slots): while it is attributed,
        corrected and tested; once a fast correction is shown back, until the post-step
        measurements complete a rolling set for the full recalibration."""
        step = self.step
        if step is None or not step.measuring:
            return False
        return step.status != StepStatus.CORRECTED or self.rolling_set() is None

    @property
    def cell_temp_c(self) -> float | None:
        """The cell temperature [degC] from the PLC's last reading; None when the PLC does not
        provide it ([line] plc_temperature) or its reading is not plausible (WindowWatch)."""
        return self.watch.temperature()[0]

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
        with self.store.batch():  # the row and the decision state it changes, or neither
            row_id = self.store.add_measurement(row)
            if reading is not None and e is not None:
                self.new_since_recal += 1
                self._good_rows += 1
                change = self._change_mm(slot, reading.c_sensor_mm, row_id)
                self._drift(slot.target, e, change, row_id)
                if self.sequential is not None:
                    self.sequential.offer({**row, "id": row_id})
            self.save_state()
        if reading is not None:
            self._watch_sensor(reading.quality)
            try:
                self.sweeps.keep(row_id, reading)
            except OSError as exc:
                raise StorageError(f"raw sweep of measurement {row_id}: {exc}") from exc
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

    def _watch_sensor(self, quality: dict[str, Any]) -> None:
        """Chart the measurement's PS (app/line/sensor_watch.py): a change says the sensor
        changed, not the robot (the `sensor` alarm)."""
        ps = SensorWatch.ps_of(quality)
        if ps is not None and (text := self.sensor_watch.update(ps)):
            self.alarm(AlarmCode.SENSOR, text, "high")

    def _change_mm(self, slot: Slot, c_sensor_mm: F64, row_id: int) -> float | None:
        """How far the centre moved since this slot's previous visit (same configuration);
        None when there is none, or when it was before a flagged step (the change spans the
        step, already known)."""
        prev = self.last_visit.get(slot.index)
        prev_id = self.visit_ids.get(slot.index, 0)
        self.last_visit[slot.index] = (slot.q_deg.copy(), np.asarray(c_sensor_mm, float).copy())
        self.visit_ids[slot.index] = row_id
        if prev is None or not np.allclose(prev[0], slot.q_deg, atol=1e-6):
            return None
        if prev_id < self.change_from_id:
            return None
        return float(np.linalg.norm(np.asarray(c_sensor_mm, float) - prev[1]))

    def _drift(self, target: str, e_mm: float, change_mm: float | None, row_id: int) -> None:
        """A residual signal while the change charts watch is slow drift: the service handles
        it (recalibration brought forward), an advisory `drift` alarm of low priority. A step
        (a change signal, or any signal before the change charts watch) may need a person to
        look at the cell: only measurements from the change point on are used, and a
        `drift_step` alarm of high priority is raised, at once when it cannot be attributed,
        else once the attribution confirms it (app/line/step_handler.py: until then a low
        `drift` alarm; a step attributed to nothing was drift)."""
        for sig in self.drift.update(target, e_mm, row_id, change_mm):
            where = "all spheres" if sig.stream == "*" else sig.stream
            stat = f"{sig.chart} {sig.value_mm:.3f} > {sig.limit_mm:.3f} mm"
            if sig.family == "residual" and self.drift.change_watching:
                self.drift_due = True
                self.alarm(
                    AlarmCode.DRIFT,
                    f"drift of {where} (residual, {stat}): recalibration brought forward",
                    "low",
                )
                continue
            if self.drift_onset_id is None:
                self.drift_onset_id = sig.onset_ref
                # attributed on pairs with the slots' visits before it: in a new cell's first
                # schedule cycle on the slots visited so far (the windows measure them again)
                attribute = sig.family == "change" or len(self.visit_ids) >= MIN_STEP_REFS
                self.step_handler.open_step(sig.onset_ref, row_id, attribute=attribute)
            what = "residual" if sig.family == "residual" else "change since the last visit"
            text = f"step of {where} ({what}, {stat}) since measurement {self.drift_onset_id}"
            if self.step is not None:
                self.step.signal = self.step.signal or text
                if self.step.status == StepStatus.PROBATION:
                    self.alarm(AlarmCode.DRIFT, f"{text}: attributing it (a step or drift?)", "low")
                    continue
            self.alarm(AlarmCode.DRIFT_STEP, step_alarm_text(text), "high")

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

    def _applied_calibration(self) -> dict[str, Any] | None:
        """The calibration of the version in force (None: none of this service's)."""
        applied = self.store.applied()
        return self.store.calibration(applied[-1]["calibration_id"] if applied else None)

    def _u_seed(self, cal: dict[str, Any] | None, seed: Sequence[tuple[str, float]]) -> list[float]:
        """The U95 seed of the version in force (app.line.accuracy): its batch calibration's
        rolling set scaled to prediction errors (`seed`, the drift charts' own), none for a
        sequential or step one (their residuals are optimistic by an unknown factor), the
        identification residuals its document carries when no calibration here made it
        (its workspace validation counts whole: app.line.accuracy.seed_count; a rolling set
        only its last schedule cycle)."""
        if cal is None:
            return document_seed(self.params.current_document())
        batch = _kind(cal["document"]) == "batch"
        return [e for _, e in seed][-len(self.schedule) :] if batch else []

    def _version_seed(self) -> list[float]:
        """The U95 seed of the version in force (`_u_seed`)."""
        cal = self._applied_calibration()
        return self._u_seed(cal, self._drift_seed(cal) if cal is not None else ())

    def _restore_drift(self) -> None:
        """After a restart: the residual charts from the stored measurements, the last visits."""
        cal = self._applied_calibration()
        seed = self._drift_seed(cal)
        self.drift.reset(seed)
        self.u_seed = self._u_seed(cal, seed)
        for r in self.store.measurements(last=2 * len(self.schedule)):
            if 0 <= r["slot"] < len(self.schedule):
                q = np.asarray(r["q_deg"], float)
                self.last_visit[int(r["slot"])] = (q, np.asarray(r["c_sensor_mm"], float))
                self.visit_ids[int(r["slot"])] = int(r["id"])

    # -- recalibration -------------------------------------------------------------------------
    def _between_windows(self) -> None:
        try:
            outcome = self.recalibrator.poll()
        except Exception as exc:  # the worker failed: not again after the restart
            self._worker_failed(exc)
            raise
        if outcome is not None:
            self.recal_done(outcome)
        if self.state in (State.IDLE, State.PAUSED):
            self.step_handler.attribute_step()
            self._maybe_recalibrate()
        self._check_space()
        self._retain()

    def _worker_failed(self, exc: BaseException) -> None:
        ids = self.recal_ids or {"train": [], "holdout": []}
        with contextlib.suppress(StorageError), self.store.batch():
            self.store.add_calibration(
                {
                    "t": self.clock.time(),
                    "status": "rejected",
                    "n_measurements": len(ids["train"]),
                    "first_id": min(ids["train"], default=None),
                    "last_id": max(ids["holdout"], default=None),
                    "gates": [],
                    "reason": f"the identification worker failed: {type(exc).__name__}: {exc}",
                }
            )
            self.recal_ids = None
            self.save_state()

    def _recal_due(self) -> bool:
        r = self.settings.recalib
        if self.force_recal or self.new_since_recal >= r.every_n:
            return True
        flagged = self.drift_onset_id is not None or self.drift_due
        return flagged and self.new_since_recal >= r.holdout_size

    def _maybe_recalibrate(self) -> None:
        if self.sequential is not None:  # "calibrate now" proposes the filter's state at once
            forced = self.force_recal and self.sequential.can_propose()
            due = forced or self.sequential.due(self._visited_views)
            if self.pending_calibration is None and due:
                self.force_recal = False
                self.recal_done(self.sequential.candidate(self.model, self.x))
            return
        if self.recalibrator.busy or self.pending_calibration is not None or not self._recal_due():
            return
        since = 0 if self.drift_onset_id is None else self.drift_onset_id - 1
        attempt = (self._good_rows, since)
        if attempt == self._incomplete:
            return  # no good measurement since the rolling set was found incomplete
        chosen = self.rolling_set()
        if chosen is None:
            self._incomplete = attempt
            return
        train, holdout = chosen
        if self.trained_on(chosen):  # nothing new to learn from: wait for a new measurement
            key = (int(train[0]["id"]), int(holdout[-1]["id"]))
            if self._skipped != key:
                self._skipped = key
                self.bus.emit(
                    "recalibration_skipped",
                    {
                        "version": self.version,
                        "first_id": key[0],
                        "last_id": key[1],
                        "reason": f"the parameters in force (version {self.version}) were"
                        " trained on these measurements; it runs after the next measurement",
                    },
                )
            return
        with self.store.batch():
            self.force_recal, self.new_since_recal = False, 0
            self.recal_ids = {
                "train": [int(t["id"]) for t in train],
                "holdout": [int(h["id"]) for h in holdout],
            }
            self.save_state()
        self._submit(train, holdout)

    def rolling_set(
        self,
    ) -> tuple[list[Mapping[str, Any]], list[Mapping[str, Any]]] | None:
        """The (training, held-out) measurements a recalibration would use now: the last ones,
        after the step's change point when one is flagged (None: not complete yet)."""
        since = 0 if self.drift_onset_id is None else self.drift_onset_id - 1
        r = self.settings.recalib
        if self.step is not None and self.step.status == StepStatus.SEVERAL:
            # no single group to correct: the cell waits for this calibration, on a schedule
            # cycle of post-step measurements (the model's larger set follows; measured: 72 for
            # the compliant model left such a new cell 35-56 windows off, 24 12-28)
            r = dataclasses.replace(r, rolling_size=min(r.rolling_n, len(self.schedule)))
        rows = self.store.measurements(
            status="ok", since_id=since, last=r.rolling_n + r.holdout_size
        )
        # the views left out (`_seen`) are not waited for: a set without them is complete
        lost = self._lost_views()
        slots = [x for x in self.schedule.slots if x.index not in lost] or self.schedule.slots
        n_slots = len(slots)
        if self.step is not None and self.step.status in (
            StepStatus.REFINING,
            StepStatus.RECOVERING,
        ):
            # a correction not yet shown back: as soon as the post-step measurements span half
            # the schedule (the identification's rank and condition gates judge the rest; the
            # recovery test judges its measurements). Once a fast correction is shown back the
            # whole schedule is asked for (measured: a half-schedule calibration then made a
            # good correction worse, 0.065 -> 0.085 mm), which the windows, still measuring for
            # the step, gather in a few windows
            n_slots = (n_slots + 1) // 2
        targets = tuple(dict.fromkeys(x.target for x in slots))
        return select_rolling(rows, n_slots, targets, r)

    def trained_on(
        self, chosen: tuple[Sequence[Mapping[str, Any]], Sequence[Mapping[str, Any]]]
    ) -> bool:
        """The parameters in force came from a calibration on exactly these measurements (a
        rolling set is contiguous: its first and last ids and its size name it)."""
        cal_id = (self.params.current_document() or {}).get("calibration_id")
        cal = None if cal_id is None else self.store.calibration(int(cal_id))
        if cal is None:
            return False
        train, holdout = chosen
        return (cal["first_id"], cal["last_id"], cal["n_measurements"]) == (
            int(train[0]["id"]),
            int(holdout[-1]["id"]),
            len(train),
        )

    def recal_wait(self) -> str:
        """Why a recalibration asked for now does not start at once, in words ("": it does)."""
        if self.sequential is not None:
            return ""
        if self.pending_calibration is not None:
            return (
                f"it waits for the decision on calibration {self.pending_calibration}"
                " (approve or reject it)"
            )
        if self.recalibrator.busy:
            return "a recalibration is running; another follows on the measurements after it"
        chosen = self.rolling_set()
        r = self.settings.recalib
        if chosen is None:
            if self.drift_onset_id is not None:
                return (
                    f"it waits for the measurements after the step (from #{self.drift_onset_id}"
                    f"; {r.rolling_n + r.holdout_size} needed, every sphere)"
                )
            return f"it waits for a complete rolling set ({r.rolling_n + r.holdout_size})"
        if self.trained_on(chosen):
            return (
                f"the parameters in force (version {self.version}) were trained on the"
                " current measurements: it runs after the next window's measurement"
            )
        return ""

    def _resubmit(self) -> None:
        """A calibration that was in flight when the service stopped runs again (the same
        measurements, the parameters in force)."""
        ids = self.recal_ids
        if ids is None or self.sequential is not None:
            return
        rows = {
            int(r["id"]): r for r in self.store.measurements_by_id(ids["train"] + ids["holdout"])
        }
        train = [rows[i] for i in ids["train"] if i in rows]
        holdout = [rows[i] for i in ids["holdout"] if i in rows]
        if train and holdout:
            self._submit(train, holdout)

    def _submit(
        self, train: Sequence[Mapping[str, Any]], holdout: Sequence[Mapping[str, Any]]
    ) -> None:
        r = self.settings.recalib
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
        self.bus.emit(
            "recalibration_started",
            {"n": len(train), "first_id": job.first_id, "last_id": job.last_id},
        )

    def recal_done(self, out: RecalOutcome | SequentialCandidate | StepCorrection) -> None:
        status = "pending" if out.passed else "rejected"
        with self.store.batch():
            cal_id = self._add_calibration(out, status)
            self.recal_ids = None
            self.save_state()
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
        if self.applies_automatically():
            self.apply_calibration(cal_id, None, "auto")
        else:
            self.pending_calibration = cal_id

    def applies_automatically(self) -> bool:
        """A calibration that passes its gates is applied at once: auto mode, and no hold
        after a rollback (`auto_hold`); otherwise it waits for an engineer's approve."""
        return self.settings.recalib.mode == "auto" and self.auto_hold is None

    def _add_calibration(
        self, out: RecalOutcome | SequentialCandidate | StepCorrection, status: str
    ) -> int:
        return self.store.add_calibration(
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

    def apply_calibration(self, cal_id: int, uid: int | None, source: str) -> int:
        """Write calibration `cal_id` as the next parameters version and put it in force (the
        document names the calibration, so that an apply killed half-way is completed at the
        next start)."""
        cal = self.store.calibration(cal_id)
        assert cal is not None, f"no calibration {cal_id}"
        try:
            version = self.params.apply({**cal["document"], "calibration_id": cal_id})
        except OSError as exc:
            raise StorageError(f"{self.params.dir}: {exc}") from exc
        self.in_force(version, cal_id, source, uid)
        return version

    def in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None:
        """Parameters `version` are current: reload them, restart the drift charts (seeded with
        the new parameters' residuals); the drift alarm and onset are cleared when the
        calibration was trained on measurements after the onset only. The database learns it
        in one transaction (the calibration's decision, the applied row, the decision state)."""
        current = self.current_params()
        assert current is not None
        self.version, self.model, self.x = current
        t = self.clock.time()
        cal = self.store.calibration(cal_id)
        with self.store.batch():
            if cal is not None and cal["status"] == "pending":
                self.store.decide_calibration(int(cal["id"]), "applied", t, uid, version)
            self.store.add_applied(t, version, cal_id, source, uid)
            self.pending_calibration = None
            kind = _kind(None if cal is None else cal["document"])
            if kind in ("sequential", "step"):
                # the filter's residuals on the rows it was fed are optimistic by an unknown
                # factor: keep the baselines (measured: reseeding gave 21 low alarms in 4 h);
                # a step correction restores the residuals of before the step
                self.drift.restart()
                self.u_seed = []
            else:
                seed = self._drift_seed(cal)
                self.drift.reset(seed)
                self.u_seed = self._u_seed(cal, seed)
            if self.sequential is not None and kind != "sequential":
                self.sequential.restart(self.model, self.x, self.params.current_document())
            onset, self.drift_due = self.drift_onset_id, False
            self.clear_alarms(AlarmCode.DRIFT, t)
            first_id = None if cal is None else int(cal["first_id"] or 0)
            after_step = first_id is not None and onset is not None and first_id >= onset
            recovering = after_step and self._suspect_open()
            if recovering:  # the interval closes when the residuals say the cell is back
                self.step_handler.corrected(t, version, cal, kind)
            elif onset is None or after_step:
                self.clear_alarms(AlarmCode.DRIFT_STEP, t)
                if kind != "step":  # a full calibration trained after the step: it is over
                    self.drift_onset_id, self.step = None, None
            self.save_state()
        self.bus.emit(
            "parameters_applied",
            {"version": version, "calibration_id": cal_id, "source": source, "uid": uid},
        )

    def _suspect_open(self) -> bool:
        """A step's suspect interval is open."""
        if self.step is None or self.step.suspect_id is None:
            return False
        row = self.store.suspect(self.step.suspect_id)
        return row is not None and row["t_end"] is None


def _kind(document: Mapping[str, Any] | None) -> str:
    """Where a calibration came from: "sequential" (app.line.inline_seq), "step" (a fast
    correction, app.line.step_fit) or "batch"."""
    kind = (document or {}).get("estimator", {}).get("kind")
    return str(kind) if kind in ("sequential", "step") else "batch"


def _sequential(document: Mapping[str, Any] | None) -> bool:
    """The calibration came from the sequential estimator (app.line.inline_seq)."""
    return _kind(document) == "sequential"
