"""A shift's figures against the truth (app/sim/shift.py): the knock's window, the windows to
the step alarm and to recovery, each window's suspect flag, what the service said moved, and
the suspect intervals scored against the windows whose true error was above the limit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from app.line.accuracy import ACCURACY_GROUP
from app.sim.line_records import WindowRecord
from app.sim.shift_result import ShiftResult, ShiftSettings, SuspectScore


def opened_s(r: WindowRecord, window_s: float) -> float:
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
        t = opened_s(r, result.window_s)
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
            r.window for r in recs if r.window >= k and covered(opened_s(r, result.window_s))
        ),
        covered_before_knock=tuple(
            r.window for r in recs if r.window < k and covered(opened_s(r, result.window_s))
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


def scored_from_json(doc: dict[str, Any]) -> ShiftResult:
    """A shift's result read back from its JSON (`ShiftResult.to_json`), with what the service
    found moved and its figures against the truth computed again."""
    result = ShiftResult.from_json(doc)
    result.attribution = attributed_group(result.suspects, knock_s(result.settings))
    evaluate(result)
    return result
