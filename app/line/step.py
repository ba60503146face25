"""A step of the cell (a knock) as the service keeps it: the record of a flagged step and its
life (`Step`, `StepStatus` and the moves it may make), the `drift_step` alarm's text, and the
recovery test that ends its suspect interval.

When the drift charts flag a step (app.line.drift, change point `onset_id`), the service opens a
`Step` and a suspect interval: from the last trustworthy measurement before the change point on,
the calibration in force may be wrong, and the bodies measured then may need measuring again.
The step is attributed and corrected (the numbers: app.line.step_fit; the handling:
app.line.step_handler). A correction in force, the suspect interval stays open until the
held-out residuals measured with it are back at their level before the step (`recovery_test`,
StepHandler.check_recovery); meanwhile the full recalibration on post-step measurements runs as
soon as they span half the schedule, and the windows go on measuring for the step.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from enum import StrEnum
from typing import Any

import numpy as np


class StepStatus(StrEnum):
    """Where a flagged step is in its life (the `Step` docstring says what each means)."""

    PROBATION = "probation"
    ATTRIBUTING = "attributing"
    PROPOSED = "proposed"
    REFINING = "refining"
    FOLLOWING = "following"
    RECOVERING = "recovering"
    CORRECTED = "corrected"
    SEVERAL = "several"
    NONE = "none"


_S = StepStatus
#: the moves a step may make (`Step.move`); a step is born on probation, or "several" when it
#: cannot be attributed; it leaves the service's decision state after a full recalibration
#: trained after it (or dropped as drift from probation)
TRANSITIONS: dict[StepStatus, frozenset[StepStatus]] = {
    _S.PROBATION: frozenset({_S.ATTRIBUTING}),
    _S.ATTRIBUTING: frozenset({_S.PROPOSED, _S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING}),
    _S.PROPOSED: frozenset({_S.ATTRIBUTING, _S.REFINING, _S.RECOVERING}),
    _S.REFINING: frozenset({_S.RECOVERING, _S.CORRECTED}),
    _S.FOLLOWING: frozenset({_S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING}),
    _S.RECOVERING: frozenset({_S.RECOVERING, _S.CORRECTED}),
    _S.CORRECTED: frozenset({_S.RECOVERING}),
    _S.SEVERAL: frozenset({_S.SEVERAL, _S.RECOVERING, _S.FOLLOWING}),
    _S.NONE: frozenset({_S.NONE}),
}
#: the statuses in which the windows measure for the step (more slots, chosen for it): until
#: the full recalibration on post-step measurements is in force (corrected: the interval has
#: closed on a fast correction, the post-step measurements are still gathered for it)
MEASURING = frozenset(
    {_S.PROBATION, _S.ATTRIBUTING, _S.FOLLOWING, _S.REFINING, _S.RECOVERING, _S.CORRECTED}
)


@dataclass
class Step:
    """The step in progress (part of the service's decision state). `status`: probation
    (flagged, not confirmed: a step or drift? no suspect interval yet), attributing
    (no correction yet), proposed (a correction waits for approval), refining (the first
    correction applied, one more window of measurements refines it), following (sequential
    estimator: the suspected group's covariance widened, its candidate awaited), corrected
    (applied; the full recalibration on post-step measurements follows), several (no single
    group: waiting for the full recalibration), none (no step found)."""

    onset_id: int
    suspect_id: int | None  # None while on probation
    t_start: float
    last_good_id: int | None
    status: StepStatus = StepStatus.ATTRIBUTING
    choice: str | None = None
    text: str = ""
    n_used: int = 0  # measurements the last attribution used
    flag_id: int | None = None  # the measurement whose chart signalled
    start_id: int | None = None  # the first measurement after the step, as located
    n_corrected: int = 0  # measurements when the first correction was made
    refine_mm: float | None = None  # how far the refinement moved points at the standoff
    refine_tries: int = 0
    signal: str = ""  # what the drift charts saw (the high alarm's text once confirmed)
    base_version: int | None = None  # the parameters the first correction was computed from
    # recovering (a correction trained after the step is in force; the interval stays open
    # until the held-out residuals measured with it are back at the level before the step)
    recover_version: int | None = None  # the correction under test
    recover_t: float | None = None  # when it went in force (where the interval ends if back)
    recover_cal_id: int | None = None
    recover_kind: str | None = None  # "step" | "batch" | "sequential"
    recover_from_id: int = 0  # its held-out measurements are the ones after this id
    full_recals: int = 0  # full recalibrations applied since the step
    recovery: str = ""  # the last recovery test, in words
    recover_n: int = 0  # measurements the last recovery test used
    change_from_before: int = 0  # the service's change_from_id before the flag (a drop restores)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(doc: Mapping[str, Any] | None) -> Step | None:
        if doc is None:
            return None
        known = {f.name for f in fields(Step)}  # a state saved by an older version: its fields
        step = Step(**{k: v for k, v in doc.items() if k in known})
        step.status = StepStatus(step.status)
        return step

    @property
    def measuring(self) -> bool:
        """The schedule serves the attribution (more slots per window, chosen for it)."""
        return self.status in MEASURING

    def move(self, to: StepStatus | str) -> None:
        """Change the status along an allowed transition (`TRANSITIONS`; ValueError else)."""
        new = StepStatus(to)
        if new not in TRANSITIONS[self.status]:
            raise ValueError(f"a step cannot go from {self.status} to {new}")
        self.status = new


def step_alarm_text(signal: str, attribution: str = "") -> str:
    """The high `drift_step` alarm's message: what the drift charts saw (`signal`) and, once
    attributed, what moved (`attribution`, the attribution's text). The one place it is built;
    the parts themselves are kept as data (`Step.signal`, the suspect interval's text)."""
    head = (
        f"{signal}: check the cell (sensor mount, spheres); recalibrating on the measurements"
        " after it"
    )
    return f"{head} | {attribution}" if attribution else head


@dataclass(frozen=True)
class Recovery:
    """Are the held-out residuals after a correction back at their level before the step?
    `verdict`: "back" (not higher at the stated confidence), "higher" (higher at it) or
    "undetermined" (too few measurements after the correction yet)."""

    verdict: str
    rms_after_mm: float
    n_after: int
    rms_before_mm: float
    n_before: int
    ratio_f: float  # (rms_after / rms_before)^2
    limit_f: float  # the F quantile it is held to (inf while undetermined)
    confidence: float

    @property
    def text(self) -> str:
        head = (
            f"held-out RMS {self.rms_after_mm:.4f} mm on {self.n_after} measurements after the"
            f" correction, {self.rms_before_mm:.4f} mm on {self.n_before} before the step"
        )
        if self.verdict == "undetermined":
            return f"{head}: too few to judge yet"
        word = "higher" if self.verdict == "higher" else "not higher"
        return (
            f"{head}: {word} at {self.confidence:.0%} confidence"
            f" (F {self.ratio_f:.2f} {'>' if self.verdict == 'higher' else '<='}"
            f" {self.limit_f:.2f})"
        )

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "text": self.text}


def recovery_test(
    before_mm: Sequence[float], after_mm: Sequence[float], confidence: float, min_after: int
) -> Recovery:
    """One-sided F test of the held-out residuals `after_mm` (norms [mm] of measurements taken
    with the correction in force, none of them used to compute it) against `before_mm` (those
    of the in-control measurements just before the step): each norm^2 carries 3 degrees of
    freedom. "higher" when (RMS after / RMS before)^2 exceeds the F(3 n_after, 3 n_before)
    quantile at `confidence`; "back" when not and at least `min_after` were measured."""
    from scipy.stats import f as f_dist

    a = np.asarray(after_mm, dtype=float)
    b = np.asarray(before_mm, dtype=float)
    rms_a = float(np.sqrt(np.mean(a**2))) if len(a) else float("nan")
    rms_b = float(np.sqrt(np.mean(b**2))) if len(b) else float("nan")
    if len(a) == 0 or len(b) == 0 or not rms_b > 0:
        return Recovery(
            "undetermined", rms_a, len(a), rms_b, len(b), float("nan"), math.inf, confidence
        )
    ratio = (rms_a / rms_b) ** 2
    limit = float(f_dist.ppf(confidence, 3 * len(a), 3 * len(b)))
    if ratio > limit:
        verdict = "higher"
    elif len(a) >= min_after:
        verdict = "back"
    else:
        verdict, limit = "undetermined", math.inf
    return Recovery(verdict, rms_a, len(a), rms_b, len(b), ratio, limit, confidence)
