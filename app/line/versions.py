"""A parameters version put in force, and what follows from it: `Versions`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do).

A calibration applied is written as the next version (its document names the calibration, so
that an apply killed half-way is completed at the next start); a version in force (applied,
rolled back to, recovered at start) is reloaded, the estimator restarts on it (app.line.jumps:
a jump's correction or a recalibration during its episode is the episode's corrected version),
the U95 seed follows (app.line.accuracy); a version trained after a jump's onset clears its
alarm, and its rolling set ends when that was a full calibration. At start the last visits come
from the stored measurements when the database holds no decision state.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from app.line.accuracy import document_seed
from app.line.host import LineHost
from app.line.jumps import JumpWatch
from app.line.residual import prediction_inflation, residual_mm
from app.line.states import AlarmCode
from app.line.store import StorageError


class Versions:
    """Calibrations applied and versions put in force, on the service `svc`; the estimator
    (`jumps`) restarts on each."""

    def __init__(self, svc: LineHost, jumps: JumpWatch) -> None:
        self.svc = svc
        self.jumps = jumps

    def apply_calibration(self, cal_id: int, uid: int | None, source: str) -> int:
        """Write calibration `cal_id` as the next parameters version and put it in force (the
        document names the calibration, so that an apply killed half-way is completed at the
        next start)."""
        svc = self.svc
        cal = svc.store.calibration(cal_id)
        assert cal is not None, f"no calibration {cal_id}"
        try:
            version = svc.params.apply({**cal["document"], "calibration_id": cal_id})
        except OSError as exc:
            raise StorageError(f"{svc.params.dir}: {exc}") from exc
        self.in_force(version, cal_id, source, uid)
        return version

    def in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None:
        """Parameters `version` are current: reload them, the estimator restarts on them, the
        U95 seed follows; a version trained on measurements after a jump's onset only clears
        its alarm, and its rolling set when it was a full calibration. The database learns it in one
        transaction (the calibration's decision, the applied row, the decision state)."""
        svc = self.svc
        current = svc.current_params()
        assert current is not None
        svc.version, svc.model, svc.x = current
        t = svc.clock.time()
        cal = svc.store.calibration(cal_id)
        with svc.store.batch():
            if cal is not None and cal["status"] == "pending":
                svc.store.decide_calibration(int(cal["id"]), "applied", t, uid, version)
            svc.store.add_applied(t, version, cal_id, source, uid)
            svc.decision.pending_calibration = None
            kind = _kind(None if cal is None else cal["document"])
            # the filter's and a jump correction's residuals on the rows they were fed are
            # optimistic by an unknown factor: no seed from them
            no_seed = kind in ("sequential", "step")
            svc.accuracy.seed = [] if no_seed else self.u_seed(cal, self.seed(cal))
            if svc.sequential is not None and kind != "sequential":
                svc.sequential.restart(svc.model, svc.x, svc.params.current_document())
            onset = svc.decision.jump_onset_id
            first_id = None if cal is None else int(cal["first_id"] or 0)
            after_onset = first_id is not None and onset is not None and first_id >= onset
            if onset is None or after_onset:
                svc.clear_alarms(AlarmCode.DRIFT_STEP, t)
                if kind != "step":  # a full calibration trained after the onset: it is over
                    svc.decision.jump_onset_id = None
            self.jumps.in_force(kind)
            svc.save_state()
        svc.bus.emit(
            "parameters_applied",
            {"version": version, "calibration_id": cal_id, "source": source, "uid": uid},
        )

    def seed(self, cal: dict[str, Any] | None) -> list[tuple[str, float]]:
        """Residuals of the parameters in force on recent good measurements: the rolling set of
        batch calibration `cal` (its training rows scaled to prediction errors), else the
        last schedule cycle and hold-out."""
        svc = self.svc
        n_train, scale = 0, 1.0
        if cal is not None and cal["first_id"] is not None and not _sequential(cal["document"]):
            rows = svc.store.measurements(since_id=int(cal["first_id"]) - 1)
            rows = [r for r in rows if r["id"] <= int(cal["last_id"])]
            n_train = int(cal["n_measurements"])
            scale = prediction_inflation(3 * n_train, len(svc.x))
        else:
            r = svc.settings.recalib
            rows = svc.store.measurements(last=len(svc.schedule) + r.holdout_size)
        if len(rows) < len(svc.schedule):
            return []
        return [
            (
                str(r["target"]),
                (scale if k < n_train else 1.0)
                * residual_mm(
                    svc.model,
                    svc.x,
                    r["q_deg"],
                    r["c_sensor_mm"],
                    svc.spheres[r["target"]],
                    r.get("temp_c"),
                ),
            )
            for k, r in enumerate(rows)
        ]

    def applied_calibration(self) -> dict[str, Any] | None:
        """The calibration of the version in force (None: none of this service's)."""
        store = self.svc.store
        applied = store.applied()
        return store.calibration(applied[-1]["calibration_id"] if applied else None)

    def u_seed(self, cal: dict[str, Any] | None, seed: Sequence[tuple[str, float]]) -> list[float]:
        """The U95 seed of the version in force (app.line.accuracy): its batch calibration's
        rolling set scaled to prediction errors (`seed`), none for a
        sequential or step one (their residuals are optimistic by an unknown factor), the
        identification residuals its document carries when no calibration here made it
        (its workspace validation counts whole: app.line.accuracy.seed_count; a rolling set
        only its last schedule cycle)."""
        if cal is None:
            return document_seed(self.svc.params.current_document())
        batch = _kind(cal["document"]) == "batch"
        return [e for _, e in seed][-len(self.svc.schedule) :] if batch else []

    def version_seed(self) -> list[float]:
        """The U95 seed of the version in force (`u_seed`)."""
        cal = self.applied_calibration()
        return self.u_seed(cal, self.seed(cal) if cal is not None else ())

    def restore(self) -> None:
        """After a restart with no decision state stored: the U95 seed and the last visits
        from the stored measurements."""
        svc = self.svc
        cal = self.applied_calibration()
        svc.accuracy.seed = self.u_seed(cal, self.seed(cal))
        for r in svc.store.measurements(last=2 * len(svc.schedule)):
            if 0 <= r["slot"] < len(svc.schedule):
                q = np.asarray(r["q_deg"], float)
                svc.decision.last_visit[int(r["slot"])] = (q, np.asarray(r["c_sensor_mm"], float))


def _kind(document: Mapping[str, Any] | None) -> str:
    """Where a calibration came from: "sequential" (app.line.inline_seq), "step" (a fast
    correction, app.line.correction) or "batch"."""
    kind = (document or {}).get("estimator", {}).get("kind")
    return str(kind) if kind in ("sequential", "step") else "batch"


def _sequential(document: Mapping[str, Any] | None) -> bool:
    """The calibration came from the sequential estimator (app.line.inline_seq)."""
    return _kind(document) == "sequential"
