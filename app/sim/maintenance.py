"""`rvis experiment maintenance --event sensor|axis|fixture [--axis N] [--seed N] --out DIR`:
a maintenance event and its procedure on the simulated line, end to end, as a plant lives it
(issue 41). On the geometric path, or (`--rendered`) with every sweep rendered and measured
through the calibrated sensor model, the sensor's own calibration included where the
procedure has one (a sensor replaced):

1. the cell commissioned (`rvis commission --sim`'s steps, in DIR/state; its robot time);
2. the in-line service runs on it (warm-up on) until the event happens at `at_s` of world time
   and the service holds the cell for maintenance (or `max_windows` pass);
3. the procedure (`rvis maintain`'s steps) on the same state directory, the world as the line
   left it, the event happened;
4. the service runs again on the directory for `after_windows` windows.

`DIR/maintenance.json` holds one row per run: the event, its seed, the window it happened in,
how many windows the service took to hold the cell (`detected_after_windows`), the first
window of the suspect interval it opened, the robot time of the procedure and of the whole
commissioning of the same cell, the workspace validation RMS before the event (the version in
force's: the commissioning's) and after the procedure, the end-to-end truth (the median true
RMS at the line's validation positions) over the windows before the event and after the
procedure, whether every body clamped from the event until the hand-over is in a suspect
interval, and whether the history was kept (versions, measurements, suspect intervals).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

from app.commission.journal import Journal
from app.config import CellConfig, load_cell
from app.config.write import dumps_cell
from app.formats.files import read_json, write_json, write_text
from app.line.launch import hold_state
from app.line.statedir import MAINTENANCE_REPORT_JSON, StateDir
from app.line.store import Store
from app.maintain.context import MaintenanceContext
from app.maintain.fixture import without_tracker
from app.maintain.record import open_record
from app.maintain.table import procedure
from app.sim.commission import SimCommissioning
from app.sim.commissioned import commission_simulated, quiet, run_steps, scripted_fields
from app.sim.line_records import WindowRecord
from app.sim.line_run import SimulatedLineRun
from app.sim.line_setup import continued_epoch, world_of
from fakes.line import SimLine
from fakes.truth import KNOCK_KINDS, Knock
from vision.sensor_model import SensorModel, load_sensor_model


@dataclass(frozen=True)
class MaintenanceRun:
    """One experiment: the event (kind, axis), the seed, when it happens [s of world time]
    (1.5 h: the cell warm, its in-line calibrations in force), how long the line runs after
    the procedure [windows] (a rolling set after the hand-over is 78 of them)."""

    event: str
    seed: int
    axis: int = 3
    at_s: float = 5400.0
    sphere: str = ""  # fixture: only this sphere replaced ("": the fixture, all of them)
    frame: bool = False  # fixture: the renewal moves the part frame (fakes.truth.Maintenance)
    after_windows: int = 100
    geometric: bool = True  # False: the rendered path (spheres, bodies, the procedure's sweeps)
    no_tracker: bool = False  # fixture: no tracker at hand (the spheres located by the robot)
    # the line runs at most until this many windows after the event's (held sooner)
    held_within: int = 20
    before_windows: int = 10  # the truth before the event: the median over these windows
    # a knock (fakes.truth.KNOCK_KINDS) in the line's `knock_window`-th window after the
    # hand-over ("": none; issue 50: a knock after a hand-over found as in a new cell)
    knock: str = ""
    knock_window: int = 4

    def __post_init__(self) -> None:
        if self.event not in ("sensor", "axis", "fixture"):
            raise ValueError("event must be sensor, axis or fixture")
        if not 1 <= self.axis <= 6:
            raise ValueError("axis must be 1..6")
        if self.frame and (self.event != "fixture" or self.sphere):
            raise ValueError("frame: the whole fixture's renewal only")
        if self.no_tracker and self.event != "fixture":
            raise ValueError("no_tracker: a fixture renewed only")
        if self.knock not in ("", *KNOCK_KINDS) or self.knock_window < 1:
            raise ValueError(f"knock: one of {', '.join(KNOCK_KINDS)}, in window 1 or later")


def run_maintenance(cfg: CellConfig, out: Path, run: MaintenanceRun) -> dict[str, Any]:
    """The experiment (module docstring) in folder `out`; its row."""
    state = StateDir(out / "state")
    say = quiet
    commissioning_robot_s = commission_simulated(cfg, state, run.seed, run.geometric)
    cell = _with_event(load_cell(state.cell), run)
    write_text(state.cell, dumps_cell(cell, "rvis experiment maintenance: the event"))
    periods = math.ceil(run.at_s / cell.simline.period_s)
    before = _line(cell, state, run, periods + run.held_within)
    k = _event_window(before.records, run.at_s)
    held_at = len(before.records)
    suspects = _suspects(state)
    n_measurements = _count_measurements(state)
    version_before = _last_version(state)
    sensor_before = _sensor_model(state, run)  # the calibration the version before measured with
    m_robot_s, m_folder = _maintain(cell, state, run, say)
    report = read_json(m_folder / MAINTENANCE_REPORT_JSON)
    steps = {s["name"]: s for s in report["steps"]}
    x_before = _version_x(cell, state, version_before)
    cell_after = _with_knock(load_cell(state.cell), state, run)
    log = _KnockLog()
    after, twin = _line_after(cell_after, state, run, x_before, sensor_before, log)
    versions = [int(a["version"]) for a in _applied(state)]
    kept = _suspects(state)
    rows = before.records
    commission_doc = read_json(state.commission_report.with_suffix(".json"))
    ws_before = _step(commission_doc, "workspace").get("rmse_mm")
    pre = [r.rmse_mm for r in rows if k - run.before_windows <= r.window < k]
    # the procedure's result: the windows measured with the version it handed over (until the
    # service's first own recalibration after it), and the version before the event in the
    # world without it at the same windows; the service's whole run after it apart
    handed = int(steps.get("handover", {}).get("results", {}).get("version", -1))
    own = [i for i, r in enumerate(after.records) if r.version == handed]
    return {
        "event": run.event,
        "axis": run.axis if run.event == "axis" else None,
        "sphere": run.sphere or None,
        "frame": run.frame,
        "path": "geometric" if run.geometric else "rendered",
        "no_tracker": run.no_tracker,
        "seed": run.seed,
        "at_s": run.at_s,
        "event_window": k,
        "held": bool(before.maintenance),
        "detected_after_windows": held_at - k + 1 if before.maintenance else None,
        "maintenance_alarm": before.maintenance,
        "suspect_from_window": _suspect_window(state, suspects, rows),
        "bodies_after_event_suspect": _bodies_covered(state, suspects, rows, k, run.sphere),
        "procedure_passed": report.get("complete", False),
        "procedure_robot_s": m_robot_s,
        "commissioning_robot_s": commissioning_robot_s,
        "validation_before_mm": ws_before,
        "validation_after_mm": _step(report, "workspace").get("rmse_mm"),
        "truth_before_mm": statistics.median(pre) if pre else None,
        "truth_after_mm": _median([after.records[i].rmse_mm for i in own]),
        "truth_after_windows": len(own),
        "truth_at_validation_mm": _step(report, "workspace").get("true_rmse_mm"),
        "truth_after_first_mm": after.records[0].rmse_mm if after.records else None,
        # the version before the event in the world without it, at the same times: what the
        # cell would measure had nothing happened (the world warms on meanwhile)
        "truth_unchanged_mm": _median([twin[i] for i in own]),
        # the line after the hand-over, the service's own recalibrations included, against
        # the version before the event held in the world without it
        "truth_line_after_mm": _median([r.rmse_mm for r in after.records]),
        "truth_line_unchanged_mm": _median(twin),
        "version_before": version_before,
        "after_windows_measured": len(after.records),
        "truth_after_by_window_mm": [round(r.rmse_mm, 4) for r in after.records],
        "versions_after_by_window": [r.version for r in after.records],
        "truth_before_by_window_mm": [round(r.rmse_mm, 4) for r in rows[max(0, k - 15) :]],
        "after_held": bool(after.maintenance),
        "changed": steps.get("reidentify", steps.get("handeye", {})).get("results", {}),
        "versions": versions,
        "measurements_kept": _count_measurements(state) >= n_measurements,
        "suspect_intervals_kept": len(kept) >= len(suspects),
        "truth": _truth(cell, run),
        **_knock_row(run, after.records, log),
    }


def _with_knock(cfg: CellConfig, state: StateDir, run: MaintenanceRun) -> CellConfig:
    """The cell with `run.knock` a second into the line's `knock_window`-th period after the
    hand-over (the world's time goes on from where the procedure left it)."""
    if not run.knock:
        return cfg
    world_s = continued_epoch(state.root)[1]
    kind = Knock.of_kind(run.knock, 0.0)
    simline = dataclasses.replace(
        cfg.simline,
        knock_at_s=world_s + (run.knock_window - 1) * cfg.simline.period_s + 1.0,
        knock_mm=kind.shift_mm,
        knock_deg=kind.tilt_deg,
        knock_kind=run.knock,
    )
    return dataclasses.replace(cfg, simline=simline)


@dataclass
class _KnockLog:
    """The line's step alarms and jumps after the hand-over, by the window they came in."""

    windows: int = 0
    limit_mm: float = math.nan
    step_windows: list[int] = dataclasses.field(default_factory=list)
    jumps: list[tuple[int, str]] = dataclasses.field(default_factory=list)

    def __call__(self, event: dict[str, Any]) -> None:
        kind = event["event"]
        if kind == "window":
            self.windows += 1
        elif kind == "alarm" and event.get("code") == "drift_step":
            self.step_windows.append(self.windows + 1)
        elif kind == "jump":
            self.jumps.append((self.windows + 1, str(event.get("group"))))


def _knock_row(run: MaintenanceRun, records: list[WindowRecord], log: _KnockLog) -> dict[str, Any]:
    """A knock after the hand-over: flagged after how many windows (the step alarm), the
    group the service found moved (its first jump from the knock's window on), and the windows
    until the true RMS was within the accuracy limit (both counted from the knock's window)."""
    if not run.knock:
        return {}
    k = run.knock_window
    flagged = [w - k + 1 for w in log.step_windows if w >= k]
    named = [g for w, g in log.jumps if w >= k]
    within = [r.window - k + 1 for r in records if r.window >= k and r.rmse_mm <= log.limit_mm]
    return {
        "knock": run.knock,
        "knock_window": k,
        "knock_flagged_after_windows": flagged[0] if flagged else None,
        "knock_attribution": named[0] if named else None,
        "knock_within_limit_after_windows": within[0] if within else None,
        "accuracy_limit_mm": log.limit_mm,
    }


def _with_event(cfg: CellConfig, run: MaintenanceRun) -> CellConfig:
    simline = dataclasses.replace(
        cfg.simline,
        maintenance_at_s=run.at_s,
        maintenance_kind=run.event,
        maintenance_axis=run.axis,
        maintenance_sphere=run.sphere,
        maintenance_frame=run.frame,
    )
    return dataclasses.replace(cfg, simline=simline)


def _sensor_model(state: StateDir, run: MaintenanceRun) -> SensorModel | None:
    """The sensor calibration the rendered line measures with: the state directory's, as
    `rvis run --sim` loads it (None: the geometric path)."""
    return None if run.geometric else load_sensor_model(state.sensor)


def _line(cfg: CellConfig, state: StateDir, run: MaintenanceRun, windows: int) -> Any:
    """The service on the state directory for `windows` windows (or until it holds the cell
    for maintenance); the run's summary."""
    with (
        hold_state(state.root, str(cfg.service.operators_group)),
        SimulatedLineRun(
            cfg, state.root, seed=run.seed, geometric=run.geometric, plan=state.plan,
            sensor_model=_sensor_model(state, run),
        ) as sim,
    ):  # fmt: skip
        return sim.run_windows(windows)


def _line_after(
    cfg: CellConfig,
    state: StateDir,
    run: MaintenanceRun,
    x_before: Any,
    sensor_before: SensorModel | None,
    on_event: _KnockLog | None = None,
) -> tuple[Any, list[float]]:
    """The service after the procedure for `after_windows` windows, and at each window the
    true error the version before the event would have in the world without the event (a
    twin of the cell: same seed, clock, warm-up; no maintenance event; on the rendered path
    measured with the sensor calibration of before, `sensor_before`)."""
    from app.sim.cell import make_cell
    from app.sim.truth import EndToEndTruth, true_rmse_mm
    from fakes.line_truth import LineTruth

    twin_rms: list[float] = []
    with (
        hold_state(state.root, str(cfg.service.operators_group)),
        SimulatedLineRun(
            cfg, state.root, seed=run.seed, geometric=run.geometric, plan=state.plan,
            sensor_model=_sensor_model(state, run),
        ) as sim,
    ):  # fmt: skip
        twin = make_cell(world_of(cfg, state.root), seed=run.seed)
        s = sim.line.settings
        twin.set_timeline(sim.clock, warmup=s.warmup, knock=s.knock, world_s=s.world_s)
        twin_line = _Twin(LineTruth(twin, sim.line.truth.validation))
        twin_truth = EndToEndTruth(twin.sensor, sensor_before, sim.truth.commands_v)

        def at(record: WindowRecord) -> None:
            t_s = record.t_h * 3600.0
            line = cast(SimLine, twin_line)  # true_rmse_mm reads only its truth
            twin_rms.append(true_rmse_mm(line, twin_truth, sim.model, x_before, t_s))

        if on_event is not None:
            on_event.limit_mm = sim.service.settings.recalib.accuracy_limit_mm
        return sim.run_windows(run.after_windows, on_window=at, on_event=on_event), twin_rms


@dataclass
class _Twin:
    """A line's truth without its line: what `true_rmse_mm` reads."""

    truth: Any


def _last_version(state: StateDir) -> int:
    applied = _applied(state)
    return int(applied[-1]["version"])


def _version_x(cfg: CellConfig, state: StateDir, version: int) -> Any:
    """A version's parameters as the service's model uses them."""
    from app.formats.params import carried_from_json

    return carried_from_json(cfg.service_model(), state.version_file(version))[1]


def _maintain(
    cfg: CellConfig, state: StateDir, run: MaintenanceRun, say: Any
) -> tuple[float, Path]:
    """The procedure of the event on the directory (`rvis maintain`'s steps), the world as the
    line left it; (its robot time [s], its folder)."""
    axis = run.axis if run.event == "axis" else None
    with ExitStack() as stack:
        held = stack.enter_context(hold_state(state.root, str(cfg.service.operators_group)))
        epoch, world_s = continued_epoch(state.root)
        sim = stack.enter_context(
            SimCommissioning(
                cfg,
                run.seed,
                geometric=run.geometric,
                world_s=world_s,
                start_epoch=epoch,
                world=world_of(cfg, state.root),
            )
        )
        folder, record = open_record(held, run.event, axis, restart=False, t=epoch, say=say)
        fields = scripted_fields(sim, cfg, held, say)
        if run.no_tracker:
            fields = without_tracker(fields)
        ctx = MaintenanceContext(
            **fields,
            out_dir=folder,
            event=run.event,
            axis=axis,
            record_id=record,
        )
        setup = {"event": run.event, "axis": axis, "simulated": True, "seed": run.seed}
        journal = Journal(folder, setup, procedure(run.event, axis))
        run_steps(ctx, journal)
        from app.commission.report import write_report

        write_report(journal)
        return ctx.robot_s, folder


def _event_window(records: list[WindowRecord], at_s: float) -> int:
    """The first window that opened at or after the event (world time = the first run's)."""
    return next((r.window for r in records if r.t_open_h * 3600.0 >= at_s), len(records) + 1)


def _suspects(state: StateDir) -> list[dict[str, Any]]:
    store = Store.read_only(state.db)
    try:
        return store.suspects()
    finally:
        store.close()


def _applied(state: StateDir) -> list[dict[str, Any]]:
    store = Store.read_only(state.db)
    try:
        return store.applied()
    finally:
        store.close()


def _count_measurements(state: StateDir) -> int:
    store = Store.read_only(state.db)
    try:
        return store.last_measurement_id()
    finally:
        store.close()


def _epoch(state: StateDir, records: list[WindowRecord]) -> float:
    """The Unix time of the first run's sim time 0 (its first window's opening, back)."""
    store = Store.read_only(state.db)
    try:
        windows = store.windows()
    finally:
        store.close()
    return float(windows[0]["t"]) - records[0].t_open_h * 3600.0 if windows else 0.0


def _suspect_window(
    state: StateDir, suspects: list[dict[str, Any]], records: list[WindowRecord]
) -> int | None:
    """The first window that opened inside the interval the service opened last."""
    if not suspects or not records:
        return None
    epoch, t0 = _epoch(state, records), float(suspects[-1]["t_start"])
    return next((r.window for r in records if epoch + r.t_open_h * 3600.0 >= t0), None)


def _bodies_covered(
    state: StateDir,
    suspects: list[dict[str, Any]],
    records: list[WindowRecord],
    k: int,
    sphere: str = "",
) -> bool:
    """Every clamp window from the event's on (to the line's stop) opened inside a suspect
    interval. One sphere moved alone (`sphere`): from its first measurement after the event
    on (until then the measuring chain is unchanged: the spheres are its reference, not part
    of it, and the windows before it were measured right)."""
    store = Store.read_only(state.db)
    try:
        windows = store.windows()
        measured = store.measurements(status="ok")
    finally:
        store.close()
    if not records or not windows:
        return False
    epoch = _epoch(state, records)
    t_event = epoch + records[k - 1].t_open_h * 3600.0 if k <= len(records) else float("inf")
    if sphere:  # the window in which the sphere was first measured after the event
        seen = [float(m["t"]) for m in measured if m["target"] == sphere and m["t"] >= t_event]
        opened = [float(w["t"]) for w in windows if seen and float(w["t"]) <= seen[0]]
        t_event = max(opened) if opened else float("inf")
    last_t = epoch + records[-1].t_open_h * 3600.0 + 1.0
    after = [w for w in windows if t_event <= w["t"] <= last_t]

    def inside(t: float) -> bool:
        return any(s["t_start"] <= t and (s["t_end"] is None or t <= s["t_end"]) for s in suspects)

    return bool(after) and all(inside(float(w["t"])) for w in after)


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def _step(doc: dict[str, Any], name: str) -> dict[str, Any]:
    for s in doc.get("steps", []):
        if s["name"] == name:
            out: dict[str, Any] = s.get("results", {})
            return out
    return {}


def _truth(cfg: CellConfig, run: MaintenanceRun) -> dict[str, Any]:
    """What the event changed, as the simulated cell knows it."""
    from app.sim.cell import make_cell
    from app.sim.line_setup import maintenance_of
    from fakes.clock import VirtualClock

    cell = make_cell(cfg, seed=run.seed)  # the cell file as commissioned: the world's spheres
    cell.set_timeline(VirtualClock(), maintenance=maintenance_of(cfg))
    return cell.maintenance_truth()


def write_rows(out: Path, rows: list[dict[str, Any]]) -> Path:
    path = out / MAINTENANCE_REPORT_JSON  # the experiment's rows: the name
    write_json(path, {"rows": rows})
    return path
