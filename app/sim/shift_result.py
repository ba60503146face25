"""A compressed shift's settings and results as data (app/sim/shift.py runs it,
app/sim/shift_score.py scores it): what the shift is, its timeline and the service's summary,
and the figures drawn from them (JSON both ways)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from app.sim.line_records import SimRunSummary, WindowRecord
from fakes.truth import KNOCK_KINDS, NO_KNOCK, Knock


@dataclass(frozen=True)
class SuspectScore:
    """The suspect intervals against the truth, per window from the knock on: `bad` windows
    (the true error of the parameters in force in the window above recovered_ratio x the
    pre-knock level), `covered` ones (the window opened inside an interval: the parameters in
    force then were the suspect ones), and any window covered before the knock (a false
    step).

    The knock's *episode* runs from the knock's window to `episode_end`: the last bad window
    before the error stays back within the ratio for `episode_gap_windows` windows in a row (or
    the shift ends). The bad windows later (a full recalibration's spread, the warm-up's drift
    hours after the knock) are not the knock's: `episode_recall` leaves them out, `recall`
    (every bad window to the end of the shift) does not."""

    bad: tuple[int, ...]
    covered: tuple[int, ...]
    covered_before_knock: tuple[int, ...]
    episode_end: int | None = None  # None: no bad window after the knock
    # the bad windows the knock caused: also above the ratio x the error the same seed had in
    # that window without the knock (the counterfactual, `ShiftResult.baseline_mm`); None:
    # no counterfactual, every bad window counts
    caused: tuple[int, ...] | None = None

    @property
    def recall(self) -> float:
        """Share of the bad windows covered, to the end of the shift (1 when none was bad)."""
        if not self.bad:
            return 1.0
        return len(set(self.bad) & set(self.covered)) / len(self.bad)

    @property
    def episode_bad(self) -> tuple[int, ...]:
        """The bad windows of the knock's episode (the knock's window to `episode_end`; with a
        counterfactual, those the knock caused)."""
        end = self.episode_end
        bad = self.bad if self.caused is None else self.caused
        return () if end is None else tuple(w for w in bad if w <= end)

    @property
    def episode_covered(self) -> tuple[int, ...]:
        """The episode's bad windows that were covered."""
        return tuple(sorted(set(self.episode_bad) & set(self.covered)))

    @property
    def episode_recall(self) -> float:
        """Share of the episode's bad windows covered (1 when none was bad)."""
        bad = self.episode_bad
        return len(self.episode_covered) / len(bad) if bad else 1.0

    @property
    def extra(self) -> int:
        """Windows covered that were not bad (after the knock) or before it."""
        return len(set(self.covered) - set(self.bad)) + len(self.covered_before_knock)

    @property
    def extra_share(self) -> float:
        """extra / all covered windows (0 when none)."""
        n = len(self.covered) + len(self.covered_before_knock)
        return self.extra / n if n else 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "bad": list(self.bad),
            "covered": list(self.covered),
            "covered_before_knock": list(self.covered_before_knock),
            "recall": self.recall,
            "extra": self.extra,
            "extra_share": self.extra_share,
            "episode_end": self.episode_end,
            "episode_bad": list(self.episode_bad),
            "episode_covered": list(self.episode_covered),
            "episode_recall": self.episode_recall,
            "caused": None if self.caused is None else list(self.caused),
        }


#: what may happen before a shift's knock (ShiftSettings.before_knock), and how many windows
#: before the knock's window (the rollback's hold is lifted in the window after it)
BEFORE_KNOCK = ("none", "restart", "rollback")
BEFORE_KNOCK_WINDOWS = 3


@dataclass(frozen=True)
class ShiftSettings:
    """The compressed shift, in virtual time: `scale` None runs it as fast as the CPU, a
    number paces it at that many sim seconds per real second (to watch it; the outcome is the
    same); `slots_per_window` None: the cell's [line] value."""

    hours: float = 8.0
    knock_at_h: float = 4.0
    # what the knock moves: sensor | fixture | joint | ... (fakes.truth.Knock), or NO_KNOCK (no
    # knock: knock_at_h is not used)
    knock: str = "sensor"
    knock_mm: float | None = None  # None: the kind's size (Knock.of_kind)
    knock_deg: float | None = None
    geometric: bool = True
    scale: float | None = None
    slots_per_window: int | None = None
    estimator: str | None = None  # "batch" | "sequential"; None: the cell's [service] estimator
    model: str | None = None  # "rigid" | "compliant"; None: the cell's [service] model
    schedule: str | None = None  # "cycle" | "adaptive" (sequential); None: the cell's
    recovered_ratio: float = 1.2  # "back": error with the service <= this x its pre-knock level
    pre_knock_windows: int = 10  # windows before the knock whose median sets the pre-knock level
    # the knock's episode ends at the last window above the ratio before this many windows in a
    # row back within it (SuspectScore.episode_end)
    episode_gap_windows: int = 10
    # what happens BEFORE_KNOCK_WINDOWS windows before the knock (issue 50: a knock after a
    # restart and after a rollback is found as in a new cell): "none"; "restart", the service
    # stopped and started again on its state directory; "rollback", the engineer's rollback to
    # the version before the one in force and the hold on automatic applies lifted (it needs
    # one: a knock after the first in-line recalibration)
    before_knock: str = "none"

    def __post_init__(self) -> None:
        if not (self.hours > 0 and 0 <= self.knock_at_h < self.hours):
            raise ValueError("need hours > 0 and 0 <= knock_at_h < hours")
        if self.scale is not None and self.scale <= 0:
            raise ValueError("scale must be > 0")
        if self.estimator not in (None, "batch", "sequential"):
            raise ValueError("estimator must be batch or sequential")
        if self.model not in (None, "rigid", "compliant"):
            raise ValueError("model must be rigid or compliant")
        if self.schedule not in (None, "cycle", "adaptive"):
            raise ValueError("schedule must be cycle or adaptive")
        if self.recovered_ratio < 1 or self.pre_knock_windows < 1 or self.episode_gap_windows < 1:
            raise ValueError(
                "recovered_ratio >= 1, pre_knock_windows >= 1 and episode_gap_windows >= 1"
            )
        if self.knock not in (*KNOCK_KINDS, NO_KNOCK):
            raise ValueError(f"knock must be one of {', '.join((*KNOCK_KINDS, NO_KNOCK))}")
        if self.before_knock not in BEFORE_KNOCK:
            raise ValueError(f"before_knock must be one of {', '.join(BEFORE_KNOCK)}")
        if self.before_knock != "none" and not self.knocked:
            raise ValueError(f"a {self.before_knock} before the knock needs a knock")

    @property
    def knocked(self) -> bool:
        return self.knock != NO_KNOCK

    def knock_size(self) -> tuple[float, float]:
        """(shift [mm], tilt or slip [deg]) of the knock (none: 0, 0)."""
        if not self.knocked:
            return 0.0, 0.0
        kind = Knock.of_kind(self.knock, 0.0)
        mm = kind.shift_mm if self.knock_mm is None else self.knock_mm
        deg = kind.tilt_deg if self.knock_deg is None else self.knock_deg
        return mm, deg


#: The line part of `rvis demo`: 45 windows, a knock after 15, as fast as the CPU.
DEMO_SHIFT = ShiftSettings(hours=0.75, knock_at_h=0.25, slots_per_window=2)

#: When a simulated shift starts (Monday 2025-01-06 06:00 UTC): part of its settings, so that
#: a seed reproduces the times stored in its state directory too, not only the outcome.
SHIFT_START_EPOCH = 1736143200.0


@dataclass
class ShiftResult:
    """The shift's timeline, the service's summary and the figures drawn from them."""

    settings: ShiftSettings
    seed: int
    scale: float | None  # the pace [sim s per real s]; None: as fast as the CPU
    summary: SimRunSummary
    drift_alarm_windows: list[int] = field(default_factory=list)
    step_alarm_windows: list[int] = field(default_factory=list)  # the high-priority ones
    applied_windows: list[int] = field(default_factory=list)
    rejected_windows: list[int] = field(default_factory=list)
    window_s: float = 20.0  # the clamp window's length [sim s]
    knock_window: int | None = None  # the first window opened after the knock
    flagged_after: int | None = None  # windows from the knock to the first step alarm
    pre_knock_rmse_mm: float = math.nan
    accuracy_limit_mm: float = math.nan  # [service] accuracy_limit_mm of the run
    floor_mm: float = math.nan  # the robot's floor (app.sim.truth.robot_floor_mm)
    recovered_after: int | None = None  # windows from the knock until back within the ratio
    real_s: float = 0.0
    # suspect intervals (sim s from the line's start) and how they cover the windows whose true
    # error was above recovered_ratio x the pre-knock level (SuspectScore)
    suspects: list[dict[str, Any]] = field(default_factory=list)
    attribution: str | None = None  # what the confirmed step was attributed to
    suspect_score: SuspectScore | None = None
    # the counterfactual: the true error per window (window 1 first) of the same seed and
    # settings without the knock (a campaign runs it once per seed); None: not run
    baseline_mm: list[float] | None = None

    @property
    def records(self) -> list[WindowRecord]:
        return self.summary.records

    @property
    def within_limit_after(self) -> int | None:
        """Windows from the knock's to the first whose true RMS is within the accuracy limit
        (issue 50's measure; None: no knock window, or none within)."""
        k, limit = self.knock_window, self.accuracy_limit_mm
        if k is None:
            return None
        within = (r.window for r in self.records if r.window >= k and r.rmse_mm <= limit)
        return next((w - k + 1 for w in within), None)

    @staticmethod
    def from_json(doc: dict[str, Any]) -> ShiftResult:
        """A result as `to_json` wrote it (to score or tabulate a finished run again)."""
        sm = dict(doc["summary"])
        records = [WindowRecord(**r) for r in sm.pop("timeline")]
        summary = SimRunSummary(**sm, records=records)
        result = ShiftResult(
            ShiftSettings(**doc["settings"]),
            int(doc["seed"]),
            None if doc["scale"] is None else float(doc["scale"]),
            summary,
            drift_alarm_windows=list(doc["drift_alarm_windows"]),
            step_alarm_windows=list(doc["step_alarm_windows"]),
            applied_windows=list(doc["applied_windows"]),
            rejected_windows=list(doc["rejected_windows"]),
            window_s=float(doc["window_s"]),
            real_s=float(doc["real_s"]),
            suspects=list(doc.get("suspects", [])),
            baseline_mm=doc.get("baseline_mm"),
            accuracy_limit_mm=float(doc.get("accuracy_limit_mm", math.nan)),
            floor_mm=float(doc.get("floor_mm", math.nan)),
        )
        return result

    def to_json(self) -> dict[str, Any]:
        return {
            "settings": dataclasses.asdict(self.settings),
            "seed": self.seed,
            "scale": self.scale,
            "window_s": self.window_s,
            "knock_window": self.knock_window,
            "flagged_after_windows": self.flagged_after,
            "pre_knock_rmse_mm": self.pre_knock_rmse_mm,
            "accuracy_limit_mm": self.accuracy_limit_mm,
            "floor_mm": self.floor_mm,
            "recovered_after_windows": self.recovered_after,
            "within_limit_after_windows": self.within_limit_after,
            "drift_alarm_windows": self.drift_alarm_windows,
            "step_alarm_windows": self.step_alarm_windows,
            "applied_windows": self.applied_windows,
            "rejected_windows": self.rejected_windows,
            "real_s": self.real_s,
            "attribution": self.attribution,
            "suspects": self.suspects,
            "suspect_score": None if self.suspect_score is None else self.suspect_score.to_json(),
            "baseline_mm": self.baseline_mm,
            "summary": self.summary.to_json(),
        }
