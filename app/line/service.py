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
calibration, a jump's episode and onset, the calibration in flight, pause, counters, the last
visit of every slot) is one snapshot in the database, written
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

A device that cannot be reached at start does not end the process: the service starts in
FAULT with a `device_unreachable` alarm and tries to open it again (app.line.startup). Every
good measurement goes into one estimator of the cell's state, which tests it for a jump (a
knock): a jump found opens a suspect interval, is named to the group that moved and corrected
(app.line.jumps; the method in docs/estimator.md).

`Service` holds the state (the decision state's snapshot and restore are here) and the life
cycle (`run`, `stop`, `crash`); its collaborators see it as app.line.host.LineHost:

    app.line.startup       the parameters in force at start; the start, devices retried
    app.line.window_loop   the loop's passes: poll, watches, a window, between windows
    app.line.slot_choice   which slot a window measures next
    app.line.recording     a measurement recorded, into the estimator
    app.line.jumps         the one estimator: a jump found, named, corrected, its interval
    app.line.decisions     when a recalibration runs, on what, whether its result is applied
    app.line.versions      a version put in force: the estimator restarts on it
    app.line.faults        alarms raised and cleared, FAULT entered, device errors noted
    app.line.operator      the operator's commands;  app.line.status: the status reply
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

from app.line.accuracy import AccuracyRecord, limit_in_force
from app.line.beyond_knock import MaintenanceNeed
from app.line.body_cycle import BodyCycle, BodySetup
from app.line.cycle import Cycle, WindowWatch
from app.line.decision_state import DecisionState
from app.line.decisions import Decisions, Rows
from app.line.estimate import sphere_sigma_mm
from app.line.events import EventBus
from app.line.fault_record import FaultRecord
from app.line.faults import Faults
from app.line.inline_seq import InlineSequential, SequentialCandidate
from app.line.jumps import JumpWatch
from app.line.measure import SphereMeasurer, SphereSensor
from app.line.operator import Operator
from app.line.params_store import MAINTENANCE_SOURCE, ParamsStore
from app.line.recalib import Posterior, Recalibrator, RecalOutcome
from app.line.recording import Recording
from app.line.roles import Roles
from app.line.schedule import Schedule
from app.line.sensor_watch import SensorWatch
from app.line.settings import ServiceSettings
from app.line.slot_choice import SlotChoice, slots_wanted
from app.line.startup import Startup, load_in_force
from app.line.statedir import StateDir
from app.line.states import RETIRED_CODES, AlarmCode, State
from app.line.station import Station
from app.line.status import status_reply
from app.line.store import StorageError, Store
from app.line.sweeps import SweepArchive
from app.line.versions import Versions
from app.line.window_loop import WindowLoop
from calib.model import SystemModel
from drivers.clock import Clock, RealClock

F64 = NDArray[np.float64]


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
        bodies: BodySetup | None = None,
    ) -> None:
        """`initial_residuals`: the identification residuals of `x_initial` (n_measurements,
        rms_mm, n_parameters) and, when its commissioning validated it across the workspace,
        `validation_errors_mm` (the norms), and `covariance` ({"active", "cov"}: the
        identification's), written into a new directory's first version (the estimator's prior
        and its unmodelled term's floor, app.line.estimate). `bodies`: the
        part type's plan and the feature sensor (app.line.body_cycle.body_setup; None: the cell
        measures no body)."""
        self.settings = s = settings or ServiceSettings()
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
        self.service_model = model  # [service] model: what it identifies
        try:
            loaded = load_in_force(
                self.params,
                self.store,
                model,
                np.asarray(x_initial, float),
                initial_residuals,
                self.clock,
            )
        except BaseException:
            self.store.close()
            raise
        self.model, self.x, self.version = loaded.model, loaded.x, loaded.version
        recalib, self.limit_basis = limit_in_force(s.recalib, self.params.document(1))
        sigma = sphere_sigma_mm(s, self.model, self.x, schedule, self.spheres)
        recalib = dataclasses.replace(recalib, jump_sigma_mm=sigma)  # resolved once, at start
        self.settings = s = dataclasses.replace(s, recalib=recalib)
        d = s.drift
        self.sensor_watch = SensorWatch(s.max_ps_mm, d.ewma_lambda, d.cusum_h, d.baseline_n)
        self.recalibrator = recalibrator or Recalibrator()
        self.sequential: InlineSequential | None = None
        if s.recalib.estimator == "sequential":
            self.sequential = InlineSequential(s.recalib, s.gates, self.spheres)
            self.sequential.restart(self.model, self.x, self.params.current_document())
        self.watch = WindowWatch(station.plc, self.clock, s.line)
        self.measurer = SphereMeasurer(station.robot, sensor, s.line)
        # the bodies' features in the cycle (app.line.body_cycle): with a feature plan
        self.body_cycle = None
        if bodies is not None:
            self.body_cycle = BodyCycle.of(bodies, s, self.watch, self.measurer, self.store)
        self.state = State.STARTING
        # what the service decided and remembers across a restart (app.line.decision_state)
        self.decision = DecisionState()
        # what the cell states about its accuracy (app.line.accuracy.AccuracyRecord)
        self.accuracy = AccuracyRecord()
        self.exit_code = 0  # 1 after an internal error: the supervisor restarts the process
        self._crash: BaseException | None = None  # from another thread (crash())
        self.fault = FaultRecord()  # the storage's and the devices' faults (its docstring)
        self._stop = threading.Event()
        self.wake = threading.Event()
        # called in the loop's thread after each window and what follows it between windows
        # (the simulated line holds the service there, its virtual time standing, to look)
        self.after_window: Callable[[], None] | None = None
        self.log = logging.getLogger("rvis.line")
        # the collaborators (module docstring), each seeing the service as app.line.host.LineHost
        self.faults = Faults(self)
        self.operator = Operator(self)  # the operator's commands (app.line.operator)
        self.jumps = JumpWatch(self)  # the one estimator and its jump test (app.line.jumps)
        self.versions = Versions(self, self.jumps)
        self.decisions = Decisions(self, self.versions)
        self.slot_choice = SlotChoice(self)
        self.recording = Recording(self, self.decisions, self.jumps)
        self.cycle = Cycle(
            self.watch,
            self.measurer,
            schedule,
            self.recording.position,
            self.recording.record,
            choose=self.slot_choice.choose,
            slots_wanted=lambda: slots_wanted(self),
        )
        self.loop = WindowLoop(self, self.operator, self.faults, self.decisions, self.jumps)
        self.startup = Startup(
            self, self.operator, self.faults, self.decisions, loaded.start_alarms
        )
        self.restore()
        # the PS chart rebuilt from the measurements since the last maintenance's hand-over (a
        # replaced sensor charts against its own baseline, not the one before it)
        rows = self.store.measurements(since_id=self.decision.maintained_since_id(), last=500)
        self.sensor_watch.replay([r["quality"] for r in rows])
        for code in RETIRED_CODES:  # raised by an older rvis: nothing would clear them
            self.clear_alarms(code)
        self.jumps.estimate.restart()
        if loaded.recovered is not None:  # an apply the database does not know yet
            self.in_force(*loaded.recovered, "recovered", None)

    def current_params(self) -> tuple[int, SystemModel, F64] | None:
        """(version, model, x) in force (params.current()), as the service identifies them: a
        rigid version (a rigid commissioning) carried into a compliant [service] model at its
        calibration temperature (calib.compliance.carry)."""
        return self.params.current(self.service_model)

    # -- the decision state (store.save_state) -------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        return {
            "params_version": self.version,
            "last_measurement_id": self.store.last_measurement_id(),
            **self.decision.to_json(),
            **self.accuracy.to_json(),
            "jumps": self.jumps.to_json(),
        }

    def save_state(self) -> None:
        self.store.save_state(self.clock.time(), self.snapshot())

    def restore(self) -> None:
        """The decision state from the database (at start, and after a storage fault)."""
        doc = self.store.load_state()
        if doc is None:  # a state directory of an older rvis: what the rows tell
            self.versions.restore()
            return
        self.decision.load_json(doc)
        self.accuracy.load_json(doc)
        self.jumps.load_json(doc.get("jumps"))
        if doc["params_version"] != self.version and self._handed_over():
            self._after_maintenance()

    def _handed_over(self) -> bool:
        """The version in force was applied by a maintenance procedure (app/maintain/) while
        the service stood."""
        applied = self.store.applied()
        last = applied[-1] if applied else None
        return (
            last is not None
            and last["version"] == self.version
            and (last["source"] == MAINTENANCE_SOURCE)
        )

    def _after_maintenance(self) -> None:
        """The first start after a maintenance procedure handed the cell back (a new sensor,
        an axis's zero, the spheres' places, the plan's views re-aimed): the measurements
        before it say nothing of the cell now. The step is over (its interval was closed by the
        hand-over), the views start afresh (none lost), the estimator starts from the handed
        over version (its U95 from its covariance and the procedure's workspace validation)."""
        self.decision.after_maintenance(self.store.last_measurement_id() + 1)
        self.accuracy.restart()
        self.log.info("started after maintenance: version %d in force", self.version)
        self.save_state()

    def maintenance_needed(self, need: MaintenanceNeed) -> None:
        """A change beyond a knock (app.line.beyond_knock): FAULT with the `maintenance`
        alarm (its text, and its fields beside it) until a maintenance procedure hands the
        cell back (or an engineer resets it)."""
        self.faults.enter_fault(AlarmCode.MAINTENANCE, need.text, need.detail())

    def posterior(self) -> Posterior | None:
        """The one estimator's posterior as a recalibration's candidate (None: identify the
        rolling set: app.line.estimate.CellEstimate.posterior)."""
        return self.jumps.estimate.posterior()

    def sphere_residuals(self) -> dict[str, dict[str, Any]]:
        """Per sphere, its measurements in the estimator's window (app.line.estimate), as the
        loop's thread last summed them up (any thread may ask)."""
        return self.jumps.estimate.sphere_summary

    # -- life cycle ---------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask `run()` to return after the current window (safe from a signal handler)."""
        self._stop.set()
        self.wake.set()

    def stopping(self) -> bool:
        """`stop()` was asked."""
        return self._stop.is_set()

    def crash(self, exc: BaseException) -> None:
        """An unexpected error in another thread of the service: the loop ends as for its own
        (safe from any thread)."""
        self._crash = exc
        self.wake.set()

    def reraise_crash(self) -> None:
        """Raise, in the loop's thread, the error another thread reported (`crash()`)."""
        if self._crash is not None:
            raise self._crash

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

    def run(self) -> None:
        """The service loop; returns after stop() with the robot home and the database closed,
        or after an internal error with the cell in FAULT and `exit_code` 1."""
        try:
            self.startup.run()
            while not self._stop.is_set():
                self.loop.step()
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
            self.faults.enter_fault(
                AlarmCode.INTERNAL_ERROR,
                f"internal error ({text}): the service stops to be restarted",
            )

    def _shutdown(self) -> None:
        self.recalibrator.close()
        self.set_state(State.STOPPED)
        with contextlib.suppress(Exception):
            self.bus.emit("stopped", {"counters": dict(self.decision.counters)})
        self.operator.cancel_queued("service stopped")  # nobody will execute them
        self.store.close()

    def set_state(self, state: State) -> None:
        if state != self.state:
            old, self.state = self.state, state
            if state != State.STOPPED:
                self.bus.emit("state", {"from": old.value, "to": state.value})

    @property
    def cell_temp_c(self) -> float | None:
        """The cell temperature [degC] from the PLC's last reading; None when the PLC does not
        provide it ([line] plc_temperature) or its reading is not plausible (WindowWatch)."""
        return self.watch.temperature()[0]

    # -- the collaborators' actions, as LineHost names them ------------------------------------
    def alarm(self, code: str, message: str, priority: str = "high") -> int:
        """Raise an alarm (stored; kept in memory while the storage fails); its id."""
        return self.faults.alarm(code, message, priority)

    def clear_alarms(self, code: str, t: float | None = None) -> int:
        """Clear the active alarms of `code`, each an `alarm_cleared` event; how many."""
        return self.faults.clear_alarms(code, t)

    def storage_fault(self, exc: StorageError) -> None:
        """The state storage failed: FAULT with the robot stopped, nothing acknowledged."""
        self.faults.storage_fault(exc)

    def note_device_error(self, exc: BaseException) -> str | None:
        """Keep `exc` as the last error of its device (the status reply's `devices`); its
        family (None: not attributable to one)."""
        return self.faults.note_device_error(exc)

    def rolling_set(self) -> tuple[Rows, Rows] | None:
        """The (training, held-out) measurements a recalibration would use now (None: not
        complete yet; app.line.decisions)."""
        return self.decisions.rolling_set()

    def trained_on(
        self, chosen: tuple[Sequence[Mapping[str, Any]], Sequence[Mapping[str, Any]]]
    ) -> bool:
        """The parameters in force came from a calibration on exactly these measurements."""
        return self.decisions.trained_on(chosen)

    def recal_wait(self) -> str:
        """Why a recalibration asked for now does not start at once, in words ("": it does)."""
        return self.decisions.recal_wait()

    def recal_done(self, out: RecalOutcome | SequentialCandidate) -> None:
        """A calibration's result: recorded, then applied at once or left pending."""
        self.decisions.recal_done(out)

    def applies_automatically(self) -> bool:
        """A calibration that passes its gates is applied at once: auto mode, and no hold
        after a rollback (`auto_hold`); otherwise it waits for an engineer's approve."""
        return self.decisions.applies_automatically()

    def apply_calibration(self, cal_id: int, uid: int | None, source: str) -> int:
        """Write calibration `cal_id` as the next parameters version and put it in force."""
        return self.versions.apply_calibration(cal_id, uid, source)

    def in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None:
        """Parameters `version` are current (app.line.versions)."""
        self.versions.in_force(version, cal_id, source, uid)
