"""A compressed shift on the simulated line (`rvis experiment shift`, the line part of the demo).

One clamp window a minute for `hours` of sim time, the cell's warm-up and a knock at `knock_at_h`
of the sensor mount, the spheres' frame or the J2 zero (`knock`); the in-line service runs
through the real drivers (SimulatedLineRun).
After every window the true error at the validation positions is recorded twice: with the
parameters in force (the service) and with the commissioning parameters (no recalibration).
From that timeline: after how many windows the step alarm flagged the knock, how many windows
until the error with the service is back within `recovered_ratio` x its pre-knock level, the
overruns (app/sim/shift_score.py); a table per hour (shift.md), the timeline (shift.json) and a
plot (shift.png): app.sim.shift_report.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.config import CellConfig
from app.line.statedir import StateDir
from app.line.store import Store
from app.sim.line_records import WindowRecord
from app.sim.line_run import SimulatedLineRun
from app.sim.shift_result import BEFORE_KNOCK_WINDOWS, SHIFT_START_EPOCH, ShiftResult, ShiftSettings
from app.sim.shift_score import attributed_group, evaluate, knock_s
from app.sim.truth import robot_floor_mm


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


def _minus(t: float | None, epoch: float) -> float | None:
    return None if t is None else t - epoch
