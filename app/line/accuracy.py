"""What the cell states about its own accuracy after each window: the expanded uncertainty U95
of a point measured now, and whether the cell can vouch for it within the plant's limit
(`[service] accuracy_limit_mm`, by default from VDA 5 and the cell's own commissioned U95:
`limit_in_force`).

The statement after a window is the one estimator's (app.line.estimate: the parameters'
posterior through the model, the unmodelled term and the measurement's noise; basis
"estimator"). Before the first measurement of a version the version's own seed speaks for it
(`statement` of `document_seed`'s norms, or of its calibration's rolling set scaled to
prediction errors: app.line.versions), as the U95 of the bodies measured then. A window whose U95
is above the limit (or unknown) is one the cell cannot vouch for: it opens (or keeps open) an
accuracy suspect interval, closed by the first window vouched for again (app.line.window_loop).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from app.config.line import RecalibSettings
from app.line.residual import prediction_inflation
from calib.uncertainty import accuracy_limit_mm, u95_mm

#: the `group_name` of an accuracy suspect interval (a step's names the group that moved)
ACCURACY_GROUP = "accuracy"
#: the end_reason of an interval closed because the cell vouches for its U95 within the limit
VOUCHED = "vouched"
#: the basis of a statement from the one estimator (app.line.jumps)
ESTIMATOR = "estimator"


@dataclass(frozen=True)
class Accuracy:
    """The statement after a window: `u95_mm` (None: no evidence), from `n` residuals (`basis`:
    "held-out", "held-out+seed", "seed", "after step", "predicted" or "none"), against
    `limit_mm`."""

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
            f"U95 {self.u95_mm:.3f} mm ({self.basis}, {self.n} residuals) {rel} limit"
            f" {self.limit_mm:.3f} mm"
        )


@dataclass
class AccuracyRecord:
    """What the cell states about its accuracy, one record (the service's `accuracy`): the
    version in force's seed residuals (`seed`, the statement before its first measurement),
    the statement after the last window (`now`; None: none yet) and the accuracy suspect
    interval it keeps open (`suspect_id`; None: none). Written by app.line.window_loop (after
    each window), app.line.versions (a new version's seed) and app.line.jumps (an interval a
    jump adopts); persisted with the decision state."""

    seed: list[float] = dataclasses.field(default_factory=list)
    now: Accuracy | None = None
    suspect_id: int | None = None

    def restart(self, seed: list[float]) -> None:
        """A version whose measurements say nothing of the cell before it (a maintenance's
        hand-over): its seed, no statement and no interval yet."""
        self.seed, self.now, self.suspect_id = seed, None, None

    def to_json(self) -> dict[str, Any]:
        """Its fields in the decision state (the keys an earlier rvis wrote)."""
        return {
            "u_seed": self.seed,
            "accuracy_suspect_id": self.suspect_id,
            "accuracy": None if self.now is None else self.now.to_json(),
        }

    def load_json(self, doc: Mapping[str, Any], version_seed: list[float]) -> None:
        """From the decision state (`to_json`'s keys; a state saved before the statement: the
        seed of the version in force, `version_seed`)."""
        seed = doc.get("u_seed")
        self.seed = [float(e) for e in seed] if seed is not None else version_seed
        self.suspect_id = doc.get("accuracy_suspect_id")
        acc = doc.get("accuracy")
        if acc is not None:
            self.now = Accuracy(
                acc["u95_mm"], int(acc["n"]), str(acc["basis"]), float(acc["limit_mm"])
            )


def statement(norms_mm: Sequence[float], basis: str, limit_mm: float) -> Accuracy:
    """The Accuracy of these residual norms."""
    u = u95_mm(norms_mm)
    return Accuracy(None if math.isnan(u) else u, len(norms_mm), basis, limit_mm)


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


def document_seed(doc: Mapping[str, Any] | None) -> list[float]:
    """The seed of a parameters version that no calibration of this service made (a
    commissioning's, imported at the first start): the errors of its validation across the
    workspace when the document carries them (`validation.errors_mm`: the commissioning's
    workspace step, tracker against rvis at positions no calibration used, as a body's points
    are measured: the version's prediction error where the line measures, which its training
    residuals understate, 0.055 against a true 0.098 mm on the simulated line); else its
    identification's `residuals` (n measurements, the RMS of their norms) scaled to prediction
    errors, as n norms of that size (the upper bound depends on their sum of squares and
    number only); none without either."""
    errors = ((doc or {}).get("validation") or {}).get("errors_mm")
    if isinstance(errors, list) and errors and all(isinstance(e, int | float) for e in errors):
        return [float(e) for e in errors]
    res = (doc or {}).get("residuals") or {}
    n, rms = res.get("n_measurements"), res.get("rms_mm")
    p = (doc or {}).get("n_parameters") or len((doc or {}).get("active") or ())
    if not isinstance(n, int) or not isinstance(rms, (int, float)) or not rms > 0 or 3 * n <= p:
        return []
    return [float(rms) * prediction_inflation(3 * n, int(p))] * n
