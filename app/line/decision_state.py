"""The service's decision state: what it has decided between windows and must remember across a
restart (persisted as one JSON document, app.line.store.Store.save_state). `DecisionState` is
its one owner; the collaborators (app.line.host.LineHost) read and change it through
`svc.decision`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def _counters() -> dict[str, int]:
    return {"windows": 0, "overruns": 0, "withdrawn": 0}


@dataclass
class DecisionState:
    """paused: the operator's pause; counters: windows, overruns, withdrawn; pending_calibration:
    a calibration waiting for an engineer's approve (its id; not persisted here: the
    calibrations' rows tell it at a start); auto_hold: a rollback in auto mode holds automatic
    applies until an engineer's resume or approve ({"version", "uid", "since_utc"}; None: not
    held); force_recal: a full recalibration asked for; new_since_recal: measurements since the
    last one; recal_ids: the calibration in flight ({"train", "held_out"} measurement ids);
    jump_onset_id: a jump's onset, the rolling set from it on; last_visit: slot -> (q_deg,
    c_sensor_mm) of its last measurement; maintained_from_id: the first measurement after a
    maintenance procedure's hand-over (the rolling sets and the views' rejections count from
    there; 0: none); episode: a jump found by the one estimator (app.line.jumps)."""

    paused: bool = False
    counters: dict[str, int] = field(default_factory=_counters)
    pending_calibration: int | None = None
    auto_hold: dict[str, Any] | None = None
    force_recal: bool = False
    new_since_recal: int = 0
    recal_ids: dict[str, list[int]] | None = None
    jump_onset_id: int | None = None
    last_visit: dict[int, tuple[F64, F64]] = field(default_factory=dict)
    maintained_from_id: int = 0
    episode: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The persisted fields (the episode goes with the estimator's: app.line.jumps)."""
        return {
            "paused": self.paused,
            "auto_hold": self.auto_hold,
            "force_recal": self.force_recal,
            "new_since_recal": self.new_since_recal,
            "jump_onset_id": self.jump_onset_id,
            "counters": dict(self.counters),
            "recal_ids": self.recal_ids,
            "last_visit": {
                str(k): [q.tolist(), c.tolist()] for k, (q, c) in self.last_visit.items()
            },
            "maintained_from_id": self.maintained_from_id,
        }

    def load_json(self, doc: dict[str, Any]) -> None:
        """The fields `to_json` wrote (a state saved before a field was kept: its default;
        before the one estimator the onset was `drift_onset_id`)."""
        self.paused = bool(doc["paused"])
        self.auto_hold = doc.get("auto_hold")
        self.force_recal = bool(doc["force_recal"])
        self.new_since_recal = int(doc["new_since_recal"])
        self.jump_onset_id = doc.get("jump_onset_id", doc.get("drift_onset_id"))
        self.counters.update({k: int(v) for k, v in doc["counters"].items()})
        self.recal_ids = doc["recal_ids"]
        self.last_visit = {
            int(k): (np.asarray(q, float), np.asarray(c, float))
            for k, (q, c) in doc["last_visit"].items()
        }
        self.maintained_from_id = int(doc.get("maintained_from_id", 0))

    def maintained_since_id(self) -> int:
        """The measurements of the cell as it is now are after this id: none from before the
        last maintenance hand-over (0: every one)."""
        return max(0, self.maintained_from_id - 1)

    def rolling_since_id(self) -> int:
        """A rolling set's measurements are after this id: from a jump's onset on, and none
        from before the last maintenance hand-over."""
        onset = 0 if self.jump_onset_id is None else self.jump_onset_id - 1
        return max(onset, self.maintained_since_id())

    def after_maintenance(self, first_id: int) -> None:
        """A maintenance procedure handed the cell back: the measurements before `first_id`
        say nothing of the cell now. No jump in hand, no onset, no calibration in flight, the
        views start afresh."""
        self.episode, self.jump_onset_id = None, None
        self.last_visit = {}
        self.maintained_from_id = first_id
        self.recal_ids, self.new_since_recal = None, 0
