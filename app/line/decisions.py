"""The service's recalibration decisions: `Decisions`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do).

Between windows: whether a recalibration is due (every `every_n` good measurements, asked for,
or brought forward by a jump the estimator found: app.line.jumps), on which measurements (the
rolling set, after the jump's onset when there is one; `rolling_set`), and what becomes of
its result: rejected, applied at once (`applies_automatically`: auto mode and no hold after a
rollback) or pending an engineer's approve. The batch identification runs in the background
(app.line.recalib.Recalibrator); a calibration in flight when the service stopped runs again
at start (`resubmit`). The sequential estimator proposes its filter's state instead
(app.line.inline_seq). A calibration applied is put in force by app.line.versions.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.line.host import LineHost
from app.line.inline_seq import SequentialCandidate
from app.line.recalib import RecalJob, RecalOutcome, as_measurements, select_rolling
from app.line.slot_choice import lost_views
from app.line.store import StorageError
from app.line.versions import Versions

F64 = NDArray[np.float64]
Rows = list[Mapping[str, Any]]


class Decisions:
    """When a recalibration runs, on what, and whether its result is applied, on the service
    `svc`; a calibration applied goes to `versions`."""

    def __init__(self, svc: LineHost, versions: Versions) -> None:
        self.svc = svc
        self.versions = versions
        self._skipped: tuple[int, int] | None = None  # the set a recalibration was skipped on
        # good measurements recorded by this process, and the (count, since) at which the
        # rolling set was last found incomplete: not looked for again until one more comes
        self._good_rows = 0
        self._incomplete: tuple[int, int] | None = None

    def counted(self) -> None:
        """A good measurement recorded (in its transaction): one more towards the next
        recalibration, and a rolling set found incomplete is looked for again."""
        self.svc.decision.new_since_recal += 1
        self._good_rows += 1

    def _recal_due(self) -> bool:
        svc = self.svc
        r = svc.settings.recalib
        if svc.decision.force_recal or svc.decision.new_since_recal >= r.every_n:
            return True
        return (
            svc.decision.jump_onset_id is not None
            and svc.decision.new_since_recal >= r.holdout_size
        )

    def maybe_recalibrate(self) -> None:
        """Between windows: a recalibration started (or the sequential estimator's candidate
        proposed) when one is due and nothing waits for a decision."""
        svc = self.svc
        if svc.sequential is not None:  # "calibrate now" proposes the filter's state at once
            forced = svc.decision.force_recal and svc.sequential.can_propose()
            due = forced or svc.sequential.due()
            if svc.decision.pending_calibration is None and due:
                svc.decision.force_recal = False
                self.recal_done(svc.sequential.candidate(svc.model, svc.x))
            return
        if (
            svc.recalibrator.busy
            or svc.decision.pending_calibration is not None
            or not self._recal_due()
        ):
            return
        since = svc.decision.rolling_since_id()
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
                svc.bus.emit(
                    "recalibration_skipped",
                    {
                        "version": svc.version,
                        "first_id": key[0],
                        "last_id": key[1],
                        "reason": f"the parameters in force (version {svc.version}) were"
                        " trained on these measurements; it runs after the next measurement",
                    },
                )
            return
        with svc.store.batch():
            svc.decision.force_recal, svc.decision.new_since_recal = False, 0
            svc.decision.recal_ids = {
                "train": [int(t["id"]) for t in train],
                "holdout": [int(h["id"]) for h in holdout],
            }
            svc.save_state()
        self._submit(train, holdout)

    def rolling_set(self) -> tuple[Rows, Rows] | None:
        """The (training, held-out) measurements a recalibration would use now: the last ones,
        after a jump's onset when there is one (None: not complete yet)."""
        svc = self.svc
        since = svc.decision.rolling_since_id()
        r = svc.settings.recalib
        rows = svc.store.measurements(
            status="ok", since_id=since, last=r.rolling_n + r.holdout_size
        )
        # the views left out (app.line.slot_choice) are not waited for: a set without them is
        # complete
        lost = lost_views(svc.store, svc.decision.maintained_since_id())
        slots = [x for x in svc.schedule.slots if x.index not in lost] or svc.schedule.slots
        targets = tuple(dict.fromkeys(x.target for x in slots))
        return select_rolling(rows, len(slots), targets, r)

    def trained_on(
        self, chosen: tuple[Sequence[Mapping[str, Any]], Sequence[Mapping[str, Any]]]
    ) -> bool:
        """The parameters in force came from a calibration on exactly these measurements (a
        rolling set is contiguous: its first and last ids and its size name it)."""
        svc = self.svc
        cal_id = (svc.params.current_document() or {}).get("calibration_id")
        cal = None if cal_id is None else svc.store.calibration(int(cal_id))
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
        svc = self.svc
        if svc.sequential is not None:
            return ""
        if svc.decision.pending_calibration is not None:
            return (
                f"it waits for the decision on calibration {svc.decision.pending_calibration}"
                " (approve or reject it)"
            )
        if svc.recalibrator.busy:
            return "a recalibration is running; another follows on the measurements after it"
        chosen = self.rolling_set()
        r = svc.settings.recalib
        if chosen is None:
            if svc.decision.jump_onset_id is not None:
                onset = svc.decision.jump_onset_id
                return (
                    f"it waits for the measurements after the jump (from #{onset}"
                    f"; {r.rolling_n + r.holdout_size} needed, every sphere)"
                )
            return f"it waits for a complete rolling set ({r.rolling_n + r.holdout_size})"
        if self.trained_on(chosen):
            return (
                f"the parameters in force (version {svc.version}) were trained on the"
                " current measurements: it runs after the next window's measurement"
            )
        return ""

    def resubmit(self) -> None:
        """A calibration that was in flight when the service stopped runs again (the same
        measurements, the parameters in force)."""
        svc = self.svc
        ids = svc.decision.recal_ids
        if ids is None or svc.sequential is not None:
            return
        rows = {
            int(r["id"]): r for r in svc.store.measurements_by_id(ids["train"] + ids["holdout"])
        }
        train = [rows[i] for i in ids["train"] if i in rows]
        holdout = [rows[i] for i in ids["holdout"] if i in rows]
        if train and holdout:
            self._submit(train, holdout)

    def _submit(
        self, train: Sequence[Mapping[str, Any]], holdout: Sequence[Mapping[str, Any]]
    ) -> None:
        svc = self.svc
        r = svc.settings.recalib
        job = RecalJob(
            svc.model,
            svc.x.copy(),
            as_measurements(train, svc.spheres),
            as_measurements(holdout, svc.spheres),
            svc.settings.gates,
            r.max_nfev,
            int(train[0]["id"]),
            int(holdout[-1]["id"]),
            svc.posterior(),
        )
        svc.recalibrator.submit(job)
        svc.bus.emit(
            "recalibration_started",
            {"n": len(train), "first_id": job.first_id, "last_id": job.last_id},
        )

    def recal_done(self, out: RecalOutcome | SequentialCandidate) -> None:
        """A calibration's result: recorded (pending or rejected), then applied at once
        (`applies_automatically`) or left pending an engineer's approve."""
        svc = self.svc
        status = "pending" if out.passed else "rejected"
        with svc.store.batch():
            cal_id = self._add_calibration(out, status)
            svc.decision.recal_ids = None
            svc.save_state()
        svc.bus.emit(
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
            self.versions.apply_calibration(cal_id, None, "auto")
        else:
            svc.decision.pending_calibration = cal_id

    def applies_automatically(self) -> bool:
        """A calibration that passes its gates is applied at once: auto mode, and no hold
        after a rollback (`auto_hold`); otherwise it waits for an engineer's approve."""
        return self.svc.settings.recalib.mode == "auto" and self.svc.decision.auto_hold is None

    def _add_calibration(self, out: RecalOutcome | SequentialCandidate, status: str) -> int:
        svc = self.svc
        return svc.store.add_calibration(
            {
                "t": svc.clock.time(),
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

    def worker_failed(self, exc: BaseException) -> None:
        """The identification worker failed: the calibration in flight recorded as rejected
        with the cause (not run again after the restart)."""
        svc = self.svc
        ids = svc.decision.recal_ids or {"train": [], "holdout": []}
        with contextlib.suppress(StorageError), svc.store.batch():
            svc.store.add_calibration(
                {
                    "t": svc.clock.time(),
                    "status": "rejected",
                    "n_measurements": len(ids["train"]),
                    "first_id": min(ids["train"], default=None),
                    "last_id": max(ids["holdout"], default=None),
                    "gates": [],
                    "reason": f"the identification worker failed: {type(exc).__name__}: {exc}",
                }
            )
            svc.decision.recal_ids = None
            svc.save_state()
