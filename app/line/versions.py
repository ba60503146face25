"""A parameters version put in force, and what follows from it: `Versions`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do).

A calibration applied is written as the next version (its document names the calibration, so
that an apply killed half-way is completed at the next start); a version in force (applied,
rolled back to, recovered at start) is reloaded, the estimator restarts on it (app.line.jumps:
a jump's correction or a recalibration during its episode is the episode's corrected version,
and its U95 comes from the version's prior until its first measurement); a version trained
after a jump's onset clears its alarm, and its rolling set ends when that was a full
calibration. At start the last visits come from the stored measurements when the database
holds no decision state.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from app.line.host import LineHost
from app.line.jumps import JumpWatch
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
        """Parameters `version` are current: reload them, the estimator restarts on them; a
        version trained on measurements after a jump's onset only clears its alarm, and its
        rolling set when it was a full calibration. The database learns it in one transaction
        (the calibration's decision, the applied row, the decision state)."""
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

    def restore(self) -> None:
        """After a restart with no decision state stored: the last visits from the stored
        measurements."""
        svc = self.svc
        for r in svc.store.measurements(last=2 * len(svc.schedule)):
            if 0 <= r["slot"] < len(svc.schedule):
                q = np.asarray(r["q_deg"], float)
                svc.decision.last_visit[int(r["slot"])] = (q, np.asarray(r["c_sensor_mm"], float))


def _kind(document: Mapping[str, Any] | None) -> str:
    """Where a calibration came from: "sequential" (app.line.inline_seq), "step" (a fast
    correction, app.line.correction) or "batch"."""
    kind = (document or {}).get("estimator", {}).get("kind")
    return str(kind) if kind in ("sequential", "step") else "batch"
