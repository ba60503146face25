"""A step of the cell (a knock) as the service keeps it: the record of a flagged step and its
life (`Step`, `StepStatus` and the moves it may make), the `drift_step` alarm's text, and the
recovery test that ends its suspect interval.

When the drift charts flag a step (app.line.drift, change point `onset_id`), the service opens a
`Step` and a suspect interval: from the last trustworthy measurement before the change point on,
the calibration in force may be wrong, and the bodies measured then may need measuring again.
The step is attributed and corrected (the numbers: app.line.step_fit; the handling:
app.line.step_handler). A correction in force, the suspect interval stays open until the
held-out residuals measured with it are shown back at their level before the step, within a
stated tolerance (an equivalence test whose repeated looks share one confidence: `recovery_test`,
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

from app.config.line import RecalibSettings


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
    MAINTENANCE = "maintenance"


_S = StepStatus
#: the moves a step may make (`Step.move`); a step is born on probation, or "several" when it
#: cannot be attributed; it leaves the service's decision state after a full recalibration
#: trained after it (or dropped as drift from probation)
TRANSITIONS: dict[StepStatus, frozenset[StepStatus]] = {
    _S.PROBATION: frozenset({_S.ATTRIBUTING, _S.MAINTENANCE}),
    _S.ATTRIBUTING: frozenset(
        {_S.PROPOSED, _S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING, _S.MAINTENANCE}
    ),
    _S.PROPOSED: frozenset(
        {_S.ATTRIBUTING, _S.REFINING, _S.RECOVERING, _S.CORRECTED, _S.MAINTENANCE}
    ),
    _S.REFINING: frozenset({_S.RECOVERING, _S.CORRECTED, _S.MAINTENANCE}),
    _S.FOLLOWING: frozenset({_S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING, _S.MAINTENANCE}),
    _S.RECOVERING: frozenset({_S.RECOVERING, _S.CORRECTED, _S.MAINTENANCE}),
    _S.CORRECTED: frozenset({_S.RECOVERING, _S.MAINTENANCE}),
    _S.SEVERAL: frozenset({_S.SEVERAL, _S.RECOVERING, _S.FOLLOWING, _S.MAINTENANCE}),
    _S.NONE: frozenset({_S.NONE}),
    _S.MAINTENANCE: frozenset({_S.MAINTENANCE}),  # ends with the maintenance's hand-over
}
#: the statuses in which the windows measure for the step (more slots, chosen for it): until
#: the full recalibration on post-step measurements is in force (corrected: the interval has
#: closed on a fast correction; several: no single group, the cell waits for that
#: calibration; in both the post-step measurements are still gathered for it)
MEASURING = frozenset(
    {
        _S.PROBATION,
        _S.ATTRIBUTING,
        _S.FOLLOWING,
        _S.REFINING,
        _S.RECOVERING,
        _S.CORRECTED,
        _S.SEVERAL,
    }
)


@dataclass
class Step:
    """The step in progress (part of the service's decision state). `status`: probation
    (flagged, not confirmed: a step or drift? no suspect interval yet), attributing
    (no correction yet), proposed (a correction waits for approval), refining (the first
    correction applied, one more window of measurements refines it), following (sequential
    estimator: the suspected group's covariance widened, its candidate awaited), corrected
    (applied; the full recalibration on post-step measurements follows), several (no single
    group: waiting for the full recalibration), none (no step found), maintenance (beyond a
    knock: the cell holds in FAULT until a maintenance procedure hands it back,
    app/line/beyond_knock.py)."""

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
    # the recovery test's looks so far, every correction of the step (each spends a share of
    # its confidence: recovery_test); a state saved before the field: 0
    recover_looks: int = 0
    recover_verdict: str = ""  # the last test's verdict on the correction under test
    recover_look_n: int = 0  # its measurements at its last look (the next: twice as many)
    # the level before the step when no measurement before it is at hand (a knock in a new
    # cell's first windows): the drift chart's or the calibration's, at the flag [mm]
    reference_mm: float | None = None
    change_from_before: int = 0  # the service's change_from_id before the flag (a drop restores)
    # a fast correction's predicted uncertainty (app.line.accuracy.with_prediction): the upper
    # bound of sigma [mm per coordinate] of the cell before the step (taken when the first
    # correction is proposed) and, with the correction in force, that combined with the
    # correction's own predicted std, for that version
    level_sigma_mm: float | None = None
    predicted_sigma_mm: float | None = None
    predicted_version: int | None = None

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
    def first_after_id(self) -> int:
        """The first measurement the step may have moved: the earlier of the flag's change
        point and the located start (a new cell's start may be located after measurements the
        knock already moved). The cell's level before the step is read before it."""
        return min(self.onset_id, self.start_id or self.onset_id)

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


def look_level(alpha: float, look: int) -> float:
    """The level at which look `look` (1, 2, ...) of a step's recovery test is made when the
    whole sequence of looks is held to `alpha`: alpha / (look (look + 1))."""
    if look < 1:
        raise ValueError(f"look {look}: the looks are counted from 1")
    return alpha / (look * (look + 1))


@dataclass(frozen=True)
class Recovery:
    """Are the held-out residuals after a correction shown back at their level before the
    step (`recovery_test`)? `verdict`: "back" (the upper bound of their RMS within the
    tolerated level), "higher" (its lower bound above it) or "undetermined" (neither, too few
    measured yet, or no level to compare with). The bounds are of the RMS after, in mm; with
    measurements before the step they are the bounds of the ratio after / before (F) times the
    RMS before."""

    verdict: str
    rms_after_mm: float
    n_after: int
    rms_before_mm: float  # the level before: RMS of the measurements before, or the reference
    n_before: int  # 0: the reference (`reference_mm`) is taken as known
    tolerated_mm: float  # max((1 + margin) level, level + tolerance)
    upper_mm: float  # upper bound of the RMS after at the look's level (nan: no look)
    lower_mm: float  # lower bound at `confidence` (nan: nothing to compare)
    look: int  # the look's number in the step's sequence (0: no look, nothing spent)
    level: float  # the look's level alpha / (look (look + 1)) (0: no look)
    confidence: float

    @property
    def text(self) -> str:
        after = (
            f"held-out RMS {self.rms_after_mm:.4f} mm on {self.n_after} measurements after the"
            " correction"
        )
        if self.n_before:
            head = f"{after}, {self.rms_before_mm:.4f} mm on {self.n_before} before the step"
        elif math.isfinite(self.rms_before_mm):
            head = f"{after}, reference {self.rms_before_mm:.4f} mm (none measured before it)"
        else:
            return f"{after}: no level before the step to compare with"
        if self.verdict == "higher":
            return (
                f"{head}: higher than the {self.tolerated_mm:.4f} mm tolerated (lower bound"
                f" {self.lower_mm:.4f} mm at {self.confidence:.0%} confidence)"
            )
        if self.look == 0:
            return f"{head}: too few to judge yet (no look)"
        bound = (
            f"upper bound {self.upper_mm:.4f} mm"
            f" {'<=' if self.verdict == 'back' else '>'} {self.tolerated_mm:.4f} mm tolerated,"
            f" look {self.look} at level {self.level:.2%}"
        )
        word = "back" if self.verdict == "back" else "not shown back"
        return f"{head}: {word} ({bound})"

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "text": self.text}


def recovery_test(
    before_mm: Sequence[float],
    after_mm: Sequence[float],
    *,
    confidence: float,
    min_after: int,
    margin: float,
    tolerance_mm: float,
    looks: int,
    last_look_n: int = 0,
    reference_mm: float | None = None,
) -> Recovery:
    """An equivalence test: are the held-out residuals `after_mm` (norms [mm] of measurements
    taken with the correction in force, none of them used to compute it) shown back at the
    level of `before_mm` (those of the in-control measurements just before the step)? "Not
    shown higher" is no evidence of "back" (Schuirmann's TOST; REFERENCE.md): "back" needs the
    upper confidence bound of the level after within a stated tolerance of the level before.

    The statistic. Each norm^2 carries 3 degrees of freedom, so (RMS after / RMS before)^2 is
    rho F(3 n_after, 3 n_before), rho the true ratio of the mean squares; its upper bound at
    level a is ratio x F_{1-a}(3 n_before, 3 n_after). The bound is of the ratio, so the
    uncertainty of the level before (from as few as 6 measurements) is in it: taking the RMS
    before as known instead (a chi-square bound on the mean square after alone) lets a level
    before that came out high by chance call "back" too easily (measured: with 6 before and 6
    measurements per window, 16 % "back" at the tolerated limit instead of at most 5 %;
    docs/results/recovery-test.md). With no measurement before the step (`before_mm` empty: a
    knock in a new cell's first windows) the level is `reference_mm`, the caller's (the
    drift chart's level before the step, or the calibration's prediction error), taken as
    known: the upper bound of the mean square after is 3 n_after MS / chi2_a(3 n_after). No
    reference: "undetermined".

    The tolerance. Back when upper bound <= max((1 + margin) x level, level + tolerance_mm),
    in RMS [mm]: `margin` says "within 1.25x" (0.25); `tolerance_mm` keeps the test possible
    when the level before is small (a ratio of a few hundredths of a mm is noise on top of
    noise: the line's 0.025 mm per coordinate). Both, rather than either alone: the relative
    margin rules for a high level, the absolute tolerance for a low one.

    The looks. The test is made again after every window as residuals accumulate, every time a
    chance of a false "back". The step's looks are counted (`looks`: those made before this
    one, across every correction tested for the step; `Step.recover_looks`) and look k is made
    at level alpha / (k (k + 1)), alpha = 1 - `confidence`: the levels add up to
    alpha k / (k + 1) < alpha, so by Bonferroni the chance of any false "back" in the step's
    whole sequence is at most alpha, however many looks and corrections it takes (no maximum
    to run out of; later looks are stricter, and their measurements more). Bonferroni ignores
    that the looks share their measurements: conservative (measured about 1 % against a 5 %
    budget at the tolerated limit). A look is made, and counts, only with at least `min_after`
    measurements after, at least twice as many as at the correction's last look
    (`last_look_n`: looks at 6, 12, 24, 48 ... of them), and a level to compare with: a look
    after every window would shrink the levels while adding little (the same measurements and
    a few more), and with the level before known to its 3 n_before degrees of freedom alone,
    a level small enough makes "back" impossible whatever is measured after.

    "higher": the lower bound of the RMS after at `confidence` above the tolerated level (no
    look, nothing spent: it only says the correction is not good enough)."""
    from scipy.stats import chi2
    from scipy.stats import f as f_dist

    a = np.asarray(after_mm, dtype=float)
    b = np.asarray(before_mm, dtype=float)
    n_a, n_b = len(a), len(b)
    rms_a = float(np.sqrt(np.mean(a**2))) if n_a else float("nan")
    if n_b:
        level_mm = float(np.sqrt(np.mean(b**2)))
    else:
        level_mm = float("nan") if reference_mm is None else float(reference_mm)
    nan = float("nan")
    if n_a == 0 or not level_mm > 0:
        return Recovery(
            "undetermined", rms_a, n_a, level_mm, n_b, nan, nan, nan, 0, 0.0, confidence
        )
    tolerated = max((1.0 + margin) * level_mm, level_mm + tolerance_mm)
    ratio = (rms_a / level_mm) ** 2
    alpha = 1.0 - confidence

    def bound(p: float) -> float:
        """The RMS after such that P(statistic beyond it) = p, upper for small p [mm]."""
        if n_b:
            return level_mm * math.sqrt(ratio * float(f_dist.ppf(1.0 - p, 3 * n_b, 3 * n_a)))
        return level_mm * math.sqrt(ratio * 3 * n_a / float(chi2.ppf(p, 3 * n_a)))

    lower = bound(confidence)
    look = looks + 1 if n_a >= max(min_after, 2 * last_look_n) else 0
    level = look_level(alpha, look) if look else 0.0
    upper = bound(level) if look else nan
    if look and upper <= tolerated:
        verdict = "back"
    elif lower > tolerated:
        verdict = "higher"
    else:
        verdict = "undetermined"
    return Recovery(
        verdict, rms_a, n_a, level_mm, n_b, tolerated, upper, lower, look, level, confidence
    )


def recovery_under(
    settings: RecalibSettings,
    before_mm: Sequence[float],
    after_mm: Sequence[float],
    *,
    looks: int = 0,
    last_look_n: int = 0,
    reference_mm: float | None = None,
) -> Recovery:
    """`recovery_test` with the confidence, minimum, margin and tolerance of `[service]`."""
    return recovery_test(
        before_mm,
        after_mm,
        confidence=settings.recovery_confidence,
        min_after=settings.recovery_min_measurements,
        margin=settings.recovery_margin,
        tolerance_mm=settings.recovery_tolerance_mm,
        looks=looks,
        last_look_n=last_look_n,
        reference_mm=reference_mm,
    )
