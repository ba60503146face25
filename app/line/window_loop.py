"""The service loop's passes: `WindowLoop`, a collaborator of app.line.service.Service that
sees it as app.line.host.LineHost (as app.line.operator's commands do).

One pass (`step`): the operator's queued commands, the PLC polled (its heartbeat, the cell
temperature and the windows it opened watched), shelved alarms past their time unshelved; then
a window when a fresh one opens and the cell is IDLE (app.line.cycle.Cycle measures it; the
cell states its accuracy after it), else what comes between windows: the background
recalibration collected, a jump the estimator found acted on (app.line.jumps), a
recalibration started when due
(app.line.decisions), the free space looked at and old events pruned; then it waits a poll. A
device's error is a FAULT, a storage failure the `state_storage` FAULT (app.line.faults).
"""

from __future__ import annotations

import logging

from app.line.accuracy import ACCURACY_GROUP, ESTIMATOR, VOUCHED, Accuracy
from app.line.beyond_knock import BLIND_WINDOWS, blind_need
from app.line.body_cycle import BodyCycle
from app.line.body_export import retain_bodies
from app.line.decisions import Decisions
from app.line.faults import Faults
from app.line.host import LineHost
from app.line.jumps import JumpWatch
from app.line.operator import Operator
from app.line.states import AlarmCode, State, suspect_json
from app.line.status import alarm_event
from app.line.store import StorageError
from drivers.errors import DeviceError

RETENTION_S = 3600.0  # how often events past [service] events_keep_days are deleted
SPC_QUIET_WINDOWS = 8  # windows without a chart's signal that clear the `spc` alarm


class WindowLoop:
    """The loop's passes on the service `svc`, with its collaborators: the operator's
    commands, the faults, a flagged step's handling and the recalibration decisions."""

    def __init__(
        self,
        svc: LineHost,
        operator: Operator,
        faults: Faults,
        decisions: Decisions,
        jumps: JumpWatch,
    ) -> None:
        self.svc = svc
        self.operator, self.faults, self.decisions, self.jumps = operator, faults, decisions, jumps
        self._unvouched = 0  # windows in a row the cell could not vouch for its U95
        self._retention_t = -float("inf")
        self._temperature_bad: bool | None = None  # known after the first poll
        self._blind: list[tuple[int, int]] = []  # windows seeing no sphere: (first id, rejected)
        self._spc_quiet = 0  # windows since the last SPC signal

    def step(self) -> None:
        """One pass of the loop (a storage failure: FAULT, then a poll's wait)."""
        svc = self.svc
        svc.reraise_crash()
        try:
            self._step_once()
        except StorageError as exc:
            svc.storage_fault(exc)
            self._pause_poll()

    def _pause_poll(self) -> None:
        svc = self.svc
        svc.clock.wait(svc.wake, svc.settings.line.poll_s)
        svc.wake.clear()

    def _step_once(self) -> None:
        svc = self.svc
        self.operator.run_commands()
        try:
            svc.watch.poll()
        except DeviceError as exc:
            if svc.state != State.FAULT:
                self.faults.device_fault(exc)
            self._pause_poll()
            return
        self._watch_heartbeat()
        self._watch_temperature()
        self._store_clamped()
        self._unshelve()
        if svc.body_cycle is not None:
            svc.body_cycle.clear_result()
            if svc.state == State.IDLE and not svc.decision.paused and svc.watch.fresh_body():
                self._body(svc.body_cycle)
                return
        if svc.state == State.IDLE and not svc.decision.paused and svc.watch.fresh_window():
            self._window()
            return
        self._between_windows()
        self._pause_poll()

    def _window(self) -> None:
        svc = self.svc
        svc.set_state(State.MEASURING)
        n = svc.decision.counters["windows"] + 1
        # the window's rising edge (the time its row holds), not now: a real clock has moved on
        # while the row was committed, and an interval from now would leave out its body
        opened = svc.watch.opened_t
        t_open = svc.clock.time() - (0.0 if opened is None else svc.clock.monotonic() - opened)
        first_id = svc.store.last_measurement_id() + 1  # the window's first measurement
        try:
            report = svc.cycle.run_window(n)
        except DeviceError as exc:
            self.faults.device_fault(exc)
            return
        svc.decision.counters["windows"] = n
        self._watch_blind(first_id)
        svc.decision.counters["overruns"] += report.overrun
        svc.decision.counters["withdrawn"] += bool(report.withdrawn)
        self.jumps.opened()  # a jump in the window's measurements: its interval first
        self.jumps.estimate.summarise()
        self._state_accuracy(t_open)
        svc.save_state()
        acc = svc.accuracy.now
        svc.bus.emit(
            "window",
            {
                **report.to_json(),
                "t_open": t_open,
                "params_version": svc.version,
                "u95_mm": None if acc is None else acc.u95_mm,
                "vouched": acc is not None and acc.vouched,
            },
        )
        svc.set_state(State.PAUSED if svc.decision.paused else State.IDLE)
        self._between_windows()
        self._bodies_after_window()
        if svc.after_window is not None:
            svc.after_window()

    def _body(self, body: BodyCycle) -> None:
        """A clamped body's features (app.line.body_cycle), with the parameters in force, the
        cell's statement for a point measured now (the last window's, else the estimator's from
        the version's prior) and the estimator's shared error at each view (app.inspect.values)."""
        svc = self.svc
        svc.set_state(State.MEASURING)
        cal = body.calibration(svc.version, svc.params.version_path(svc.version))
        try:
            report = body.run_body(
                svc.decision.counters["windows"], svc.version, cal, self.statement_u95_mm(),
                svc.cell_temp_c, self.jumps.point_cov_mm2,
            )  # fmt: skip
        except DeviceError as exc:
            self.faults.device_fault(exc)
            return
        svc.bus.emit("body", {**report.to_json(), "params_version": svc.version})
        self._export(body)
        svc.set_state(State.PAUSED if svc.decision.paused else State.IDLE)

    def _export(self, body: BodyCycle) -> None:
        """The bodies' files into the results directory; while it cannot be written the
        `results_dir` alarm stands (the files wait in the database), cleared when it can."""
        svc = self.svc
        if body.writer is None:
            return
        written, why = body.export()
        active = bool(svc.store.active_alarms(AlarmCode.RESULTS_DIR))
        if why and not active:
            svc.alarm(
                AlarmCode.RESULTS_DIR,
                f"results directory not writable ({why}): the bodies' files wait in the"
                " database and are written when it is",
                "medium",
            )
        elif not why and active:
            svc.clear_alarms(AlarmCode.RESULTS_DIR)
        if written:
            svc.bus.emit("results_written", {"files": written})

    def statement_u95_mm(self) -> float | None:
        """The U95 the cell states for a point measured now (None: none)."""
        now = self.svc.accuracy.now
        if now is not None and now.u95_mm is not None:
            return now.u95_mm
        return self.jumps.statement_u95_mm()

    def _bodies_after_window(self) -> None:
        """Now that the cell measured itself: the bodies of suspect intervals corrected since
        they were measured computed again, the charts' signals attributed, the files written."""
        body = self.svc.body_cycle
        if body is None:
            return
        done = body.reevaluate_pending(self.svc.params.version_path, self.statement_u95_mm())
        for interval in done:
            self.svc.bus.emit("reevaluated", interval)
        self._spc(body)
        self._export(body)

    def _spc(self, body: BodyCycle) -> None:
        """The charts' signals since the last window, attributed now that the cell measured
        itself (app.inspect.spc): one `spc` event each window they come, and one `spc` alarm
        that says the newest while it stands, cleared after SPC_QUIET_WINDOWS windows without
        a signal."""
        svc = self.svc
        texts = body.attribute_signals(
            svc.settings.recalib.accuracy_limit_mm, self.statement_u95_mm()
        )
        active = svc.store.active_alarms(AlarmCode.SPC)
        if texts:
            self._spc_quiet = 0
            svc.bus.emit("spc", {"signals": texts})
            text = "; ".join(texts)
            if active:
                svc.store.update_alarm_message(int(active[0]["id"]), text)
            else:
                svc.alarm(AlarmCode.SPC, text, "low")
        elif active:
            self._spc_quiet += 1
            if self._spc_quiet >= SPC_QUIET_WINDOWS:
                svc.clear_alarms(AlarmCode.SPC)

    def _watch_blind(self, first_id: int) -> None:
        """Windows in a row in which no view saw its sphere where the parameters put it (each
        rejected, or off by more than `[service] maintenance_step_mm`, where its last good
        visit was within it): at BLIND_WINDOWS, a change far beyond a knock
        (app.line.beyond_knock): the step's suspect interval from the first of them, the cell
        held for maintenance."""
        svc = self.svc
        ids = list(range(first_id, svc.store.last_measurement_id() + 1))
        rows = svc.store.measurements_by_id(ids) if ids else []  # the window's, any status
        if not rows:
            return  # a window without a measurement says nothing
        bound = svc.settings.recalib.maintenance_step_mm
        # the slots' last good measurements before the window: a view counts as blind when it
        # saw its sphere within the bound before (a change, not a cell never calibrated)
        before = svc.store.measurements(before_id=first_id, last=4 * len(svc.schedule))
        was = {int(r["slot"]): abs(r["residual_mm"] or 0.0) <= bound for r in before}
        far = [
            r
            for r in rows
            if was.get(int(r["slot"]), False)
            and (r["status"] != "ok" or abs(r["residual_mm"] or 0.0) > bound)
        ]
        if len(far) < len(rows):
            self._blind = []
            return
        self._blind.append((first_id, len(far)))
        if len(self._blind) < BLIND_WINDOWS or svc.state == State.FAULT:
            return
        need = blind_need(len(self._blind), sum(n for _, n in self._blind))
        self.jumps.hold_blind(self._blind[0][0], need)

    def _state_accuracy(self, t_open: float) -> None:
        """After a window: the U95 of a point measured now from the estimator (app.line.jumps),
        stated for the window's bodies; a window the cell cannot vouch for within the limit
        opens an accuracy suspect interval (from when it opened), the first one vouched for
        again closes it."""
        svc = self.svc
        rows = svc.store.measurements(last=4 * len(svc.schedule))
        limit = svc.settings.recalib.accuracy_limit_mm
        acc = Accuracy(
            self.jumps.statement_u95_mm(), self.jumps.estimate.n_rows(), ESTIMATOR, limit
        )
        svc.accuracy.now = acc
        self._watch_vouched(acc)
        with svc.store.batch():
            svc.store.state_window_u95(acc.u95_mm)
            open_id = svc.accuracy.suspect_id
            # (a jump's open interval speaks for these windows already)
            if not acc.vouched and open_id is None and not self.jumps.interval_open():
                # from the last measurement before this window (the last one vouched for) on
                before = [r for r in rows if r["t"] < t_open]
                first_id = int(before[-1]["id"]) + 1 if before else svc.store.last_measurement_id()
                svc.accuracy.suspect_id = sid = svc.store.open_suspect(
                    {
                        "t_start": float(before[-1]["t"]) if before else t_open,
                        "last_good_id": int(before[-1]["id"]) if before else None,
                        "onset_id": first_id,
                        "params_version": svc.version,
                        "group_name": ACCURACY_GROUP,
                        "text": f"the cell cannot vouch for its accuracy: {acc.text()}",
                    }
                )
                opened = svc.store.suspect(sid)
            elif acc.vouched and open_id is not None:
                row = svc.store.suspect(open_id) or {}
                svc.store.update_suspect(
                    open_id,
                    t_end=t_open,
                    end_reason=VOUCHED,
                    end_version=svc.version,
                    text=f"{row.get('text', '')}; vouched for again: {acc.text()}",
                )
                svc.accuracy.suspect_id, opened = None, svc.store.suspect(open_id)
            else:
                opened = None
        if opened is not None:
            svc.bus.emit("suspect_interval", suspect_json(opened))

    def _watch_vouched(self, acc: Accuracy) -> None:
        """`[service] accuracy_alarm_windows` windows in a row the cell cannot vouch for its
        U95 within the limit: the `accuracy` alarm, and a full recalibration unless a jump's
        episode is handling it; cleared by the first window vouched for."""
        svc = self.svc
        if acc.vouched:
            if self._unvouched:
                svc.clear_alarms(AlarmCode.ACCURACY)
            self._unvouched = 0
            return
        self._unvouched += 1
        if self._unvouched != svc.settings.recalib.accuracy_alarm_windows:
            return
        handled = self.jumps.handling()
        action = "a jump's correction is under way" if handled else "recalibrating"
        if not handled:
            svc.decision.force_recal = True
        svc.alarm(
            AlarmCode.ACCURACY,
            f"the cell has not vouched for its accuracy for {self._unvouched} windows"
            f" ({acc.text()}): {action}",
            "high",
        )

    def _unshelve(self) -> None:
        svc = self.svc
        t = svc.clock.time()
        for alarm_id in svc.store.unshelve_expired(t):
            row = svc.store.alarm(alarm_id)
            data = {"id": alarm_id} if row is None else alarm_event(row, "raised")
            svc.bus.emit("alarm_unshelved", data, level=logging.WARNING, t=t)

    def _watch_heartbeat(self) -> None:
        svc = self.svc
        alarms = svc.store.active_alarms(code=AlarmCode.PLC_HEARTBEAT)
        if svc.watch.lost and not alarms:
            svc.alarm(
                AlarmCode.PLC_HEARTBEAT, "PLC heartbeat lost: no window is used until it returns"
            )
        elif svc.watch.alive and alarms:
            svc.clear_alarms(AlarmCode.PLC_HEARTBEAT)

    def _watch_temperature(self) -> None:
        """A `temperature` alarm while the PLC should provide the cell temperature and does
        not (raised once, cleared when a plausible value returns, or when the cell file no
        longer reads the word); meanwhile measurements are stored without one and the compliant
        model leaves its thermal term out. The database is asked only when that changes."""
        svc = self.svc
        why = svc.watch.temperature()[1]
        if bool(why) == self._temperature_bad:
            return  # nothing changed since the last poll: no query
        active = svc.store.active_alarms(code=AlarmCode.TEMPERATURE)
        if why and not active:
            svc.alarm(
                AlarmCode.TEMPERATURE,
                f"{why}: no cell temperature; measurements are stored without one and the"
                " thermal term is left out until a plausible value returns",
                "medium",
            )
        elif not why and active:
            svc.clear_alarms(AlarmCode.TEMPERATURE)
        self._temperature_bad = bool(why)

    def _store_clamped(self) -> None:
        """The windows the PLC opened since the last poll, each with the body clamped in it
        ([line] plc_body_id; WindowWatch): one row each, taken from the queue once stored (a
        storage failure keeps them until a reset finds it writing again)."""
        svc = self.svc
        clamped = svc.watch.clamped
        while clamped and not svc.fault.storage_failed:
            svc.store.add_window(*clamped[0])
            clamped.popleft()

    def _between_windows(self) -> None:
        svc = self.svc
        try:
            outcome = svc.recalibrator.poll()
        except Exception as exc:  # the worker failed: not again after the restart
            self.decisions.worker_failed(exc)
            raise
        if outcome is not None:
            self.decisions.recal_done(outcome)
        if svc.state in (State.IDLE, State.PAUSED):
            self.jumps.act()
            self.decisions.maybe_recalibrate()
        self.faults.check_space()
        self._retain()

    def _retain(self) -> None:
        """At most once an hour: events older than [service] events_keep_days are deleted (in
        short transactions), and the documents of calibrations rejected more than
        rejected_keep_days ago dropped; the record (measurements, calibrations with their
        figures, applied versions, alarms, the operators' audit) is kept."""
        svc = self.svc
        now = svc.clock.monotonic()
        if now - self._retention_t < RETENTION_S:
            return
        self._retention_t = now
        s, t = svc.settings.ops, svc.clock.time()
        if s.events_keep_days > 0:
            n = svc.store.prune_events(t - s.events_keep_days * 86400.0)
            if n:
                svc.log.info(
                    "retention: %d events older than %g days deleted", n, s.events_keep_days
                )
        if s.rejected_keep_days > 0:
            n = svc.store.prune_rejected_documents(t - s.rejected_keep_days * 86400.0)
            if n:
                svc.log.info("retention: documents of %d rejected calibrations dropped", n)
        retain_bodies(svc.store, svc.settings, t, svc.log)  # [results] keep_days
