"""What the cell states about its own accuracy after each window: the expanded uncertainty U95
of a point measured now, and whether the cell can vouch for it within the plant's limit
(`[service] accuracy_limit_mm`, by default from VDA 5 and the cell's own commissioned U95:
`limit_in_force`).

The statement is the one estimator's (app.line.estimate: the parameters' posterior, or before
a version's first measurement its prior, through the model, the unmodelled term and the
measurement's noise; basis "estimator"), as the U95 of the bodies measured then. A window whose
U95 is above the limit (or unknown) is one the cell cannot vouch for: it opens (or keeps open) an
accuracy suspect interval, closed by the first window vouched for again (app.line.window_loop).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from app.config.line import RecalibSettings
from calib.uncertainty import accuracy_limit_mm, u95_mm

#: the `group_name` of an accuracy suspect interval (a step's names the group that moved)
ACCURACY_GROUP = "accuracy"
#: the end_reason of an interval closed because the cell vouches for its U95 within the limit
VOUCHED = "vouched"
#: the basis of a statement from the one estimator (app.line.jumps)
ESTIMATOR = "estimator"


@dataclass(frozen=True)
class Accuracy:
    """The statement after a window: `u95_mm` (None: no evidence), from the `n` measurements
    in the estimator's window (`basis`: "estimator"; a state of an earlier rvis, others),
    against `limit_mm`."""

    u95_mm: float | None
    n: int
    basis: str
    limit_mm: float

    @property
    def vouched(self) -> bool:
        """The cell vouches for U95 within the limit."""
        return self.u95_mm is not None and self.u95_mm <= self.limit_mm

    def to_json(self) -> dict[str, Any]:
        return {
            "u95_mm": self.u95_mm,
            "n": self.n,
            "basis": self.basis,
            "limit_mm": self.limit_mm,
            "vouched": self.vouched,
        }

    def text(self) -> str:
        if self.u95_mm is None:
            return f"U95 unknown (no evidence yet) > limit {self.limit_mm:.3f} mm"
        rel = "<=" if self.vouched else ">"
        return (
            f"U95 {self.u95_mm:.3f} mm ({self.basis}, {self.n} measurements) {rel} limit"
            f" {self.limit_mm:.3f} mm"
        )


@dataclass
class AccuracyRecord:
    """What the cell states about its accuracy, one record (the service's `accuracy`): the
    statement after the last window (`now`; None: none yet) and the accuracy suspect interval
    it keeps open (`suspect_id`; None: none). Written by app.line.window_loop (after each
    window) and app.line.jumps (an interval a jump adopts); persisted with the decision
    state."""

    now: Accuracy | None = None
    suspect_id: int | None = None

    def restart(self) -> None:
        """A version whose measurements say nothing of the cell before it (a maintenance's
        hand-over): no statement and no interval yet."""
        self.now, self.suspect_id = None, None

    def to_json(self) -> dict[str, Any]:
        """Its fields in the decision state (the keys an earlier rvis wrote)."""
        return {
            "accuracy_suspect_id": self.suspect_id,
            "accuracy": None if self.now is None else self.now.to_json(),
        }

    def load_json(self, doc: Mapping[str, Any]) -> None:
        """From the decision state (`to_json`'s keys)."""
        self.suspect_id = doc.get("accuracy_suspect_id")
        acc = doc.get("accuracy")
        if acc is not None:
            self.now = Accuracy(
                acc["u95_mm"], int(acc["n"]), str(acc["basis"]), float(acc["limit_mm"])
            )


def limit_in_force(
    recalib: RecalibSettings, first: Mapping[str, Any] | None
) -> tuple[RecalibSettings, str]:
    """The settings with the limit in force: `accuracy_limit_mm` as set, or (0) by
    calib.uncertainty.accuracy_limit_mm from the cell's own U95, its first version's workspace
    validation (`first`: its document), for the default tolerance; with the reason."""
    if recalib.accuracy_limit_mm > 0:
        return recalib, "[service] accuracy_limit_mm"
    errors = ((first or {}).get("validation") or {}).get("errors_mm")
    own = u95_mm([float(e) for e in errors]) if errors else None
    limit, why = accuracy_limit_mm(0.0, own)
    return dataclasses.replace(recalib, accuracy_limit_mm=limit), why
