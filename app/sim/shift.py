"""A compressed shift on the simulated line (`rvis experiment shift`, the line part of the demo).

One clamp window a minute for `hours` of sim time, the cell's warm-up and a knock at `knock_at_h`
of the sensor mount, the spheres' frame or the J2 zero (`knock`); the in-line service runs
through the real drivers (SimulatedLineRun).
After every window the true error at the validation positions is recorded twice: with the
parameters in force (the service) and with the commissioning parameters (no recalibration).
From that timeline: after how many windows the step alarm flagged the knock, how many windows
until the error with the service is back within `recovered_ratio` x its pre-knock level, the
overruns; a table per hour (shift.md), the timeline (shift.json) and a plot (shift.png).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.config import CellConfig
from app.formats.files import dumps_json
from app.line.accuracy import ACCURACY_GROUP
from app.line.statedir import StateDir
from app.line.store import Store
from app.sim.line_run import SimRunSummary, SimulatedLineRun, WindowRecord
from app.sim.truth import robot_floor_mm
from fakes.truth import KNOCK_KINDS, NO_KNOCK, Knock

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
        result.attribution = attributed_group(result.suspects, knock_s(result.settings))
        evaluate(result)
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


def shift_config(cfg: CellConfig, s: ShiftSettings) -> CellConfig:
    """The cell with the shift's knock (and slots per window) in [simline] and [line]."""
    knock_mm, knock_deg = s.knock_size()
    simline = dataclasses.replace(
        cfg.simline,
        knock_at_s=s.knock_at_h * 3600.0 if s.knocked else -1.0,
        knock_mm=knock_mm,
        knock_deg=knock_deg,
        knock_kind=s.knock if s.knocked else cfg.simline.knock_kind,
    )
    line, service = cfg.line, cfg.service
    if s.slots_per_window is not None:
        line = dataclasses.replace(line, slots_per_window=s.slots_per_window)
    if s.estimator is not None:
        service = dataclasses.replace(service, estimator=s.estimator)
    if s.schedule is not None:
        service = dataclasses.replace(service, schedule=s.schedule)
    if s.model is not None:  # the commissioning keeps the cell's [calibration] model
        service = dataclasses.replace(service, model=s.model)
    return dataclasses.replace(cfg, simline=simline, line=line, service=service)


def n_windows(cfg: CellConfig, s: ShiftSettings) -> int:
    return max(1, round(s.hours * 3600.0 / cfg.simline.period_s))


class _EventLog:
    """Which window each drift alarm and calibration outcome came after."""

    def __init__(self, result: ShiftResult) -> None:
        self.result = result

    def __call__(self, event: dict[str, Any]) -> None:
        r, kind = self.result, event["event"]
        # the window in progress (alarms) or the next one (parameters applied between windows)
        window = r.summary.windows + 1
        if kind == "alarm" and event.get("code") in ("drift", "drift_step"):
            r.drift_alarm_windows.append(window)
            if event.get("code") == "drift_step":
                r.step_alarm_windows.append(window)
        elif kind == "parameters_applied" and event.get("source") == "auto":
            r.applied_windows.append(window)
        elif kind == "calibration" and event.get("status") == "rejected":
            r.rejected_windows.append(window)


def run_shift(
    cfg: CellConfig,
    state_dir: str | Path,
    settings: ShiftSettings | None = None,
    *,
    seed: int = 0,
    on_window: Callable[[WindowRecord], None] | None = None,
) -> ShiftResult:
    """Run the compressed shift in `state_dir` (a fresh directory) and evaluate it."""
    s = settings or ShiftSettings()
    cfg = shift_config(cfg, s)
    t0 = time.perf_counter()
    with SimulatedLineRun(
        cfg,
        state_dir,
        seed=seed,
        geometric=s.geometric,
        pace=s.scale,
        start_epoch=SHIFT_START_EPOCH,
    ) as run:
        result = ShiftResult(s, seed, s.scale, run.summary, window_s=cfg.simline.window_s)
        result.accuracy_limit_mm = run.service.settings.recalib.accuracy_limit_mm
        result.floor_mm = robot_floor_mm(run.line)
        log = _EventLog(result)

        def windows(n: int) -> None:
            run.run_windows(n, on_window=on_window, on_event=log)

        if s.before_knock != "none":
            windows(event_window(cfg, s))
            if s.before_knock == "restart":
                run.restart_service()
            else:
                _roll_back(run, windows)
        windows(n_windows(cfg, s))
        epoch = run.clock.start_epoch
    store = Store(StateDir(state_dir).db)  # (a service held for maintenance has closed its own)
    try:
        result.suspects = [
            {**r, "t_start_s": r["t_start"] - epoch, "t_end_s": _minus(r["t_end"], epoch)}
            for r in store.suspects()
        ]
    finally:
        store.close()
    result.attribution = attributed_group(result.suspects, knock_s(s))
    result.real_s = time.perf_counter() - t0
    evaluate(result)
    return result


def event_window(cfg: CellConfig, s: ShiftSettings) -> int:
    """The window after which `s.before_knock` happens: BEFORE_KNOCK_WINDOWS before the first
    window opened after the knock (ValueError: the knock comes too early for one)."""
    knock_window = math.floor(s.knock_at_h * 3600.0 / cfg.simline.period_s) + 1
    k = knock_window - BEFORE_KNOCK_WINDOWS
    if k < 1:
        raise ValueError(
            f"a {s.before_knock} before the knock needs the knock in window"
            f" {BEFORE_KNOCK_WINDOWS + 1} or later (it comes in window {knock_window})"
        )
    return k


def _roll_back(run: SimulatedLineRun, windows: Callable[[int], None]) -> None:
    """The engineer's rollback to the version before the one in force and the operator's
    resume (the hold on automatic applies lifted; a calibration that landed meanwhile rejected
    first), carried out by the service in its next window (`windows(n)` runs the line to its
    n-th); ValueError without an earlier version."""
    applied = [int(r["version"]) for r in run.service.store.applied()]
    earlier = [v for v in applied if v != run.service.version]
    if not earlier:
        raise ValueError(
            "a rollback needs an earlier version: a knock after the first recalibration"
        )
    svc = run.service
    replies = [svc.request("rollback", {"version": earlier[-1]}), svc.request("resume")]
    windows(run.summary.windows + 1)
    answers = [f.result(60.0) for f in replies]
    if answers[-1].get("held") and svc.decision.pending_calibration is not None:
        replies = [
            svc.request("reject", {"calibration": svc.decision.pending_calibration}),
            svc.request("resume"),
        ]
        windows(run.summary.windows + 1)
        answers = [f.result(60.0) for f in replies]
    if not all(a.get("ok") for a in answers) or answers[-1].get("held"):
        raise RuntimeError(f"the rollback before the knock was not carried out: {answers}")


def _opened_s(r: WindowRecord, window_s: float) -> float:
    """When the window opened [sim s] (older runs: the record's time less a window)."""
    return r.t_open_h * 3600.0 if math.isfinite(r.t_open_h) else r.t_h * 3600.0 - window_s


def knock_s(s: ShiftSettings) -> float:
    """When the shift's knock came [s into the shift]; a shift without one: 0 (a step found in
    it is a false one, named as a knock's would be)."""
    return 3600.0 * s.knock_at_h if s.knocked else 0.0


def attributed_group(suspects: list[dict[str, Any]], knock_s: float) -> str | None:
    """What the service found moved for the knock at `knock_s` [s into the shift]: the group
    of the first step interval (a confirmed step) not over before it; None when no step was
    confirmed. (Before: the last interval's, which named a drift the charts flagged later in
    the warm-up, "several", for a knock corrected right.)"""
    steps = [
        s
        for s in suspects
        if s.get("group_name") != ACCURACY_GROUP
        and (s.get("t_end_s") is None or s["t_end_s"] >= knock_s)
    ]
    return str(steps[0]["group_name"]) if steps else None


def _minus(t: float | None, epoch: float) -> float | None:
    return None if t is None else t - epoch


def evaluate(result: ShiftResult) -> None:
    """Knock window, windows to the step alarm, pre-knock level and windows to recovery."""
    s, recs = result.settings, result.records
    mark_suspect(result)
    if not s.knocked:
        return
    after = [r.window for r in recs if r.t_h * 3600.0 - result.window_s >= s.knock_at_h * 3600.0]
    if not after:
        return
    k = result.knock_window = after[0]
    alarms = [w for w in result.drift_alarm_windows if w >= k]
    result.flagged_after = alarms[0] - k + 1 if alarms else None
    before = [r.rmse_mm for r in recs if r.window < k][-s.pre_knock_windows :]
    if not before:
        return
    result.pre_knock_rmse_mm = float(np.median(before))
    limit = s.recovered_ratio * result.pre_knock_rmse_mm
    back = [r.window for r in recs if r.window >= k and r.rmse_mm <= limit]
    result.recovered_after = back[0] - k + 1 if back else None
    result.suspect_score = score_suspects(result, limit)


def mark_suspect(result: ShiftResult) -> None:
    """Each window's `suspect`: it opened inside a suspect interval (a step's, or one the cell
    could not vouch for its U95 within the limit in), or its stated U95 is above the limit or
    none was stated."""
    limit = result.accuracy_limit_mm
    for r in result.records:
        t = _opened_s(r, result.window_s)
        inside = any(
            s["t_start_s"] <= t and (s["t_end_s"] is None or t < s["t_end_s"])
            for s in result.suspects
        )
        unvouched = r.u95_mm is None or (math.isfinite(limit) and r.u95_mm > limit)
        r.suspect = inside or unvouched


def score_suspects(result: ShiftResult, limit_mm: float) -> SuspectScore:
    """Which windows the suspect intervals cover (at the time each window opened, when the
    parameters whose true error it records were in force) against those whose true error
    exceeds `limit_mm`."""
    k = result.knock_window or 10**9

    def covered(t_s: float) -> bool:
        return any(
            s["t_start_s"] < t_s and (s["t_end_s"] is None or t_s < s["t_end_s"])
            for s in result.suspects
        )

    recs = result.records
    bad = tuple(r.window for r in recs if r.window >= k and r.rmse_mm > limit_mm)
    caused = None
    base = result.baseline_mm
    if base is not None:
        ratio = result.settings.recovered_ratio
        caused = tuple(
            r.window
            for r in recs
            if r.window in bad and (r.window > len(base) or r.rmse_mm > ratio * base[r.window - 1])
        )
    return SuspectScore(
        bad=bad,
        covered=tuple(
            r.window for r in recs if r.window >= k and covered(_opened_s(r, result.window_s))
        ),
        covered_before_knock=tuple(
            r.window for r in recs if r.window < k and covered(_opened_s(r, result.window_s))
        ),
        episode_end=episode_end(
            bad if caused is None else caused, result.settings.episode_gap_windows
        ),
        caused=caused,
    )


def episode_end(bad: tuple[int, ...], gap: int) -> int | None:
    """The last of the knock's bad windows (`bad`: ascending, from the knock's window on): the
    last one before `gap` windows in a row that were not bad; None when none was bad."""
    if not bad:
        return None
    end = bad[0]
    for w in bad[1:]:
        if w - end - 1 >= gap:
            break
        end = w
    return end


def hourly_rows(result: ShiftResult) -> list[dict[str, float]]:
    """Per sim hour: mean temperature, mean true RMSE without and with recalibration, and the
    calibrations applied during that hour."""
    rows = []
    applied = set(result.applied_windows)
    hours = math.ceil(result.settings.hours)
    for h in range(hours):
        recs = [r for r in result.records if h <= r.t_h < h + 1]
        if not recs:
            continue
        rows.append(
            {
                "hour": float(h),
                "temp_c": float(np.mean([r.temp_c for r in recs])),
                "without_mm": float(np.mean([r.rmse_commissioning_mm for r in recs])),
                "with_mm": float(np.mean([r.rmse_mm for r in recs])),
                "max_with_mm": float(np.max([r.rmse_mm for r in recs])),
                "applied": float(sum(r.window in applied for r in recs)),
            }
        )
    return rows


def time_text(scale: float | None) -> str:
    """How the shift's time ran, for its report."""
    return "virtual time" if scale is None else f"virtual time paced at x{scale:g}"


def _windows_text(n: int | None, limit: int) -> str:
    return "never" if n is None else f"{n} window{'s' * (n != 1)} (target <= {limit})"


def summary_lines(result: ShiftResult) -> list[str]:
    """The shift's must-show figures, one per line."""
    s, sm = result.settings, result.summary
    tail = [
        stated_accuracy_text(result),
        _alarms_text(result),
        f"overruns: {sm.overruns} (target 0); windows {sm.windows}, measurements {sm.measurements}"
        f" ({sm.rejected} rejected), calibrations applied {sm.calibrations_applied}, rejected"
        f" {sm.calibrations_rejected}",
        f"true RMSE at the end: {sm.true_rmse_final_mm:.4f} mm with the service,"
        f" {result.records[-1].rmse_commissioning_mm:.4f} mm without recalibration"
        if result.records
        else "no window ran",
    ]
    if not s.knocked:
        return [
            f"no knock; a step attributed to: {result.attribution or 'nothing'} (target nothing)",
            f"suspect intervals: {_spans(result) or 'none'}",
            *tail,
        ]
    mm, deg = s.knock_size()
    axis = "J2" if s.knock == "joint" else s.knock
    what = {"sensor": "the sensor mount", "fixture": "the spheres' frame"}.get(
        s.knock, "one sphere alone" if s.knock == "sphere" else f"the {axis} zero"
    )
    size = {"sensor": f"{mm:g} mm / {deg:g} deg", "fixture": f"{mm:g} mm / {deg:g} deg"}.get(
        s.knock, f"{mm:g} mm" if s.knock == "sphere" else f"{deg:g} deg"
    )
    return [
        f"knock of {what} ({size}) at {s.knock_at_h:g} h (window {result.knock_window}):"
        f" flagged by the step alarm after {_windows_text(result.flagged_after, 3)},"
        f" attributed to: {result.attribution or 'nothing'}",
        f"true RMS within the limit ({result.accuracy_limit_mm:g} mm) after"
        f" {_windows_text(result.within_limit_after, 6)}; back within"
        f" {s.recovered_ratio:g}x of the pre-knock error ({result.pre_knock_rmse_mm:.4f} mm)"
        f" after {_windows_text(result.recovered_after, 3)}",
        _suspects_text(result),
        *tail,
    ]


def stated_accuracy_text(result: ShiftResult) -> str:
    """What the service stated about its accuracy against the truth: the windows whose true
    RMS is within the stated U95, the median U95, the suspect windows and those above the
    limit."""
    recs = result.records
    stated = [r.u95_mm for r in recs if r.u95_mm is not None]
    if not recs or not stated:
        return "stated accuracy: no U95 stated"
    covered = sum(r.u95_mm is not None and r.rmse_mm <= r.u95_mm for r in recs)
    limit = result.accuracy_limit_mm
    above = [r for r in recs if r.rmse_mm > limit]
    return (
        f"stated accuracy: U95 median {float(np.median(stated)):.4f} mm (limit {limit:g} mm);"
        f" true RMS within the stated U95 in {covered} of {len(recs)} windows (target >= 95 %);"
        f" {sum(r.suspect for r in recs)} windows suspect, {sum(r.suspect for r in above)} of"
        f" the {len(above)} above the limit (target >= 98 %)"
    )


def _suspects_text(result: ShiftResult) -> str:
    sc = result.suspect_score
    if sc is None:
        return "suspect intervals: no knock window"
    return (
        f"suspect intervals: {_spans(result) or 'none'}; they cover {len(sc.covered)} windows"
        f" after the knock, {len(sc.bad)} were above {result.settings.recovered_ratio:g}x (recall"
        f" {100 * sc.recall:.0f} %, target 100 %), {sc.extra} covered that were not"
        f" ({100 * sc.extra_share:.0f} % of the covered, target <= 10 %); over the knock's"
        f" episode ({_episode_span(result.knock_window, sc.episode_end)}):"
        f" {len(sc.episode_covered)} of {len(sc.episode_bad)} above covered (recall"
        f" {100 * sc.episode_recall:.0f} %, target >= 95 %)"
    )


def _spans(result: ShiftResult) -> str:
    return ", ".join(
        f"{x['t_start_s'] / 3600:.3f}-"
        + ("open" if x["t_end_s"] is None else f"{x['t_end_s'] / 3600:.3f}")
        + f" h ({x['size_mm'] or 0:.3f} mm)"
        for x in result.suspects
    )


def _episode_span(knock_window: int | None, end: int | None) -> str:
    return "no window above" if end is None else f"windows {knock_window}-{end}"


def _alarms_text(result: ShiftResult) -> str:
    """Step alarm episodes (windows with a new one) before and after the knock."""
    k = result.knock_window or 10**9
    steps = set(result.step_alarm_windows)
    before = len({w for w in steps if w < k})
    after = len(steps) - before
    return f"step alarms (windows with one) before the knock: {before}; after it: {after}"


def markdown(result: ShiftResult, command: str) -> str:
    lines = [
        "# Compressed shift on the simulated line",
        "",
        f"Generated by `{command}` (seed {result.seed}, {time_text(result.scale)},"
        f" {'geometric' if result.settings.geometric else 'rendered'} measurements,"
        f" {result.real_s:.0f} s real time). True RMS error at the line's validation positions"
        " after every window: with the service (parameters in force) and without recalibration"
        " (the commissioning parameters).",
        "",
        *[f"- {line}" for line in summary_lines(result)],
        "",
        "| hour | temperature [C] | RMSE without recalibration [mm] | RMSE with the service [mm]"
        " | max with the service [mm] | calibrations applied |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in hourly_rows(result):
        lines.append(
            f"| {r['hour']:.0f}-{r['hour'] + 1:.0f} | {r['temp_c']:.2f} | {r['without_mm']:.4f} |"
            f" {r['with_mm']:.4f} | {r['max_with_mm']:.4f} | {r['applied']:.0f} |"
        )
    lines += ["", "![true error over the shift](shift.png)", ""]
    return "\n".join(lines)


def plot_shift(
    path: Path, knock_at_h: float, draw: Callable[[Any], None], *, own_axes: bool = False
) -> None:
    """The shift's figure: `draw(ax)` puts the curves, this the knock, axes and legend
    (`own_axes`: draw labelled the axes itself)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    draw(ax)
    ax.axvline(knock_at_h, color="k", ls="--", lw=1, label="knock")
    if not own_axes:
        ax.set_xlabel("shift time [h]")
        ax.set_ylabel("true RMS error at the validation positions [mm]")
        ax.set_ylim(bottom=0)
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot(result: ShiftResult, path: Path) -> None:
    def draw(ax: Any) -> None:
        t_h = [r.t_h for r in result.records]
        ax.plot(
            t_h, [r.rmse_commissioning_mm for r in result.records], label="without recalibration"
        )
        ax.plot(t_h, [r.rmse_mm for r in result.records], label="with the service")
        by_window = {r.window: r.t_h for r in result.records}
        applied = [by_window[w] for w in result.applied_windows if w in by_window]
        if applied:
            ax.plot(applied, [0.0] * len(applied), "g^", ms=5, label="calibration applied")

    plot_shift(path, result.settings.knock_at_h, draw)


def write_report_files(
    out: Path, stem: str, md: str, doc: Any, draw: Callable[[Path], None]
) -> list[Path]:
    """`<stem>.md`, `<stem>.json` and `<stem>.png` in `out` (the figure by `draw(path)`)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}{ext}" for ext in (".md", ".json", ".png")]
    paths[0].write_text(md)
    paths[1].write_text(dumps_json(doc))
    draw(paths[2])
    return paths


def write_outputs(result: ShiftResult, out: Path, command: str, stem: str = "shift") -> list[Path]:
    """`<stem>.md`, `<stem>.json` and `<stem>.png` in `out`."""
    md = markdown(result, command).replace("(shift.png)", f"({stem}.png)")
    return write_report_files(out, stem, md, result.to_json(), lambda png: plot(result, png))


def estimator_rows(results: dict[str, ShiftResult]) -> list[dict[str, Any]]:
    """One row per way of keeping the cell calibrated: no recalibration (the commissioning
    parameters, from the first run), then each estimator: the time-averaged true RMSE over the
    shift, before and after the knock, the worst window, knock flag and recovery."""
    first = next(iter(results.values()))
    k = first.knock_window or 10**9

    def row(name: str, r: ShiftResult, e: list[float]) -> dict[str, Any]:
        w = [rec.window for rec in r.records]
        return {
            "name": name,
            "mean_mm": float(np.mean(e)),
            "before_mm": float(np.mean([x for x, i in zip(e, w, strict=True) if i < k] or [0])),
            "after_mm": float(np.mean([x for x, i in zip(e, w, strict=True) if i >= k] or [0])),
            "max_mm": float(np.max(e)),
        }

    out = [row("no recalibration", first, [x.rmse_commissioning_mm for x in first.records])]
    for name, r in results.items():
        out.append(
            row(name, r, [x.rmse_mm for x in r.records])
            | {
                "flagged_after": r.flagged_after,
                "recovered_after": r.recovered_after,
                "applied": r.summary.calibrations_applied,
                "rejected": r.summary.calibrations_rejected,
                "overruns": r.summary.overruns,
            }
        )
    return out


def estimators_markdown(results: dict[str, ShiftResult], command: str) -> str:
    """The comparison table of `rvis experiment shift --estimator compare`."""
    first = next(iter(results.values()))
    lines = [
        "# Keeping the cell calibrated over a shift: no recalibration, batch, sequential",
        "",
        f"Generated by `{command}` (seed {first.seed}, {time_text(first.scale)}, the same simulated"
        f" cell, warm-up and knock at {first.settings.knock_at_h:g} h in every run; model:"
        f" {first.settings.model or 'the cell file'}). True RMS"
        " error at the line's validation positions after every window, averaged over the shift"
        " and before/after the knock. Batch: identification on the rolling set (24 + 4 held"
        " out) every 24 measurements or when drift is flagged; sequential: an extended Kalman"
        " update per measurement (app/line/inline_seq.py), a candidate every 8 accepted updates,"
        " the same gates; adaptive: the sequential estimator choosing the most informative"
        " planned configuration instead of the next in turn.",
        "",
        "| | mean RMSE [mm] | before the knock [mm] | after the knock [mm] | worst window [mm]"
        " | knock flagged after | back within 1.2x after | applied / rejected | overruns |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in estimator_rows(results):
        extra = (
            f" {_n(r['flagged_after'])} | {_n(r['recovered_after'])} |"
            f" {r['applied']} / {r['rejected']} | {r['overruns']} |"
            if "applied" in r
            else " - | - | - | - |"
        )
        lines.append(
            f"| {r['name']} | {r['mean_mm']:.4f} | {r['before_mm']:.4f} | {r['after_mm']:.4f} |"
            f" {r['max_mm']:.4f} |" + extra
        )
    lines += ["", "![true error over the shift](shift-estimators.png)", ""]
    return "\n".join(lines)


def _n(windows: int | None) -> str:
    return "never" if windows is None else f"{windows} windows"


def plot_estimators(results: dict[str, ShiftResult], path: Path) -> None:
    first = next(iter(results.values()))

    def draw(ax: Any) -> None:
        t_h = [r.t_h for r in first.records]
        ax.plot(t_h, [r.rmse_commissioning_mm for r in first.records], label="no recalibration")
        for name, res in results.items():
            ax.plot([r.t_h for r in res.records], [r.rmse_mm for r in res.records], label=name)

    plot_shift(path, first.settings.knock_at_h, draw)


def write_estimators(results: dict[str, ShiftResult], out: Path, command: str) -> list[Path]:
    """`shift-estimators.md`, `.json` and `.png` in `out`."""
    md, doc = estimators_markdown(results, command), {"rows": estimator_rows(results)}
    return write_report_files(
        out, "shift-estimators", md, doc, lambda png: plot_estimators(results, png)
    )
