"""What the cell states about its own accuracy after each window: the expanded uncertainty U95
(calib.uncertainty) of a point measured now, from the in-line check standard, and whether the
cell can vouch for it within the plant's limit (`[service] accuracy_limit_mm`).

The evidence is the residuals of the sphere measurements taken with the parameters in force (not
trained on them: held out), the last `n_max` of them (a schedule cycle: every configuration);
while fewer were measured, the version's own seed tops them up (the training residuals of its
calibration scaled to prediction errors, as the drift charts are seeded: app.line.drift). A
flagged step changes the evidence: only the measurements from its change point on count (the
seed and the measurements before it describe a cell that is no longer there), so U95 grows at
once with the first measurement after a knock, and comes down with the measurements of the
correction in force; while they are fewer than a cycle, a fast correction's predicted
uncertainty (the level before the step and the correction's covariance) stands for it as long
as they do not contradict it (`with_prediction`). A window whose U95 is above the limit (or
unknown: no evidence yet) is one the cell cannot vouch for: it opens (or keeps open) an
accuracy suspect interval, closed by the first window vouched for again.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from app.config.line import RecalibSettings
from app.line.drift import prediction_inflation
from calib.uncertainty import accuracy_limit_mm, norm_quantile, shown_larger, u95_mm

#: the `group_name` of an accuracy suspect interval (a step's names the group that moved)
ACCURACY_GROUP = "accuracy"
#: the end_reason of an interval closed because the cell vouches for its U95 within the limit
VOUCHED = "vouched"
#: the basis of a statement after a step: the measurements after it, or a fast correction's
#: predicted uncertainty that they do not contradict
AFTER_STEP = "after step"
PREDICTED = "predicted"
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


def evidence(
    rows: Sequence[Mapping[str, Any]],
    version: int,
    onset_id: int | None,
    seed_mm: Sequence[float],
    n_max: int,
) -> tuple[list[float], str]:
    """(residual norms [mm], basis) that speak for the parameters `version` now (module
    docstring): the good measurements `rows` (id order) taken with it, from `onset_id` on when
    a step is flagged, the last `n_max`; topped up with `seed_mm` without a step (`seed_count`
    of them, the newest)."""
    held = [
        float(r["residual_mm"])
        for r in rows
        if r.get("residual_mm") is not None
        and int(r["params_version"]) == version
        and (onset_id is None or int(r["id"]) >= onset_id)
    ][-n_max:]
    if onset_id is not None:
        return held, AFTER_STEP if held else "none"
    top = list(seed_mm)[-seed_count(len(seed_mm), len(held), n_max) :] if len(held) < n_max else []
    if not held:
        return top, "seed" if top else "none"
    return top + held, "held-out+seed" if top else "held-out"


def seed_count(n_seed: int, n_held: int, n_max: int) -> int:
    """How many of a seed of `n_seed` norms top up `n_held` held-out ones (< n_max): the seed
    speaks for the version as a schedule cycle would, and the held-out residuals displace it
    in proportion as they fill the cycle; a seed of at most `n_max` norms tops the held-out up
    to `n_max` (its newest), a longer one (a commissioning's workspace validation at more
    positions than a cycle has slots) counts whole at first, the share of it the cycle has
    not filled yet after (a validation of 50 positions: 48 of them beside 1 held-out norm, 25
    beside 12)."""
    return max(n_max - n_held, math.ceil(n_seed * (n_max - n_held) / n_max))


def statement(norms_mm: Sequence[float], basis: str, limit_mm: float) -> Accuracy:
    """The Accuracy of these residual norms."""
    u = u95_mm(norms_mm)
    return Accuracy(None if math.isnan(u) else u, len(norms_mm), basis, limit_mm)


def with_prediction(
    acc: Accuracy, norms_mm: Sequence[float], sigma_mm: float | None, n_max: int
) -> Accuracy:
    """After a fast correction of a step: its predicted uncertainty instead of the post-step
    residuals' bound while they are few. `sigma_mm`: the correction's predicted sigma per
    coordinate (the upper bound of the cell's level before the step, the evidence of a cycle
    then, combined in quadrature with the correction's own predicted std over the measuring
    volume: GUM's combination of the two independent terms), None without one; `norms_mm`:
    the residuals measured with it in force after the step (`acc`'s evidence). The prediction
    stands while they are at least one and fewer than a cycle (`n_max`), do not show a larger
    sigma (calib.uncertainty.shown_larger, 95 %) and do not bound it lower themselves; else
    `acc`. Basis "predicted"."""
    if sigma_mm is None or acc.basis != AFTER_STEP or not 0 < len(norms_mm) < n_max:
        return acc
    if shown_larger(norms_mm, sigma_mm):
        return acc
    u = norm_quantile() * sigma_mm
    if acc.u95_mm is not None and acc.u95_mm <= u:
        return acc
    return Accuracy(u, len(norms_mm), PREDICTED, acc.limit_mm)


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
