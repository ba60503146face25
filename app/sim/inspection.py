"""The body's gauge studies on the simulated line, as plants accept an in-line gauge
(`rvis experiment gauge`, `rvis experiment correlation`; REFERENCE.md "Gauge studies").

Both start from a cell commissioned on the simulated line by `rvis commission --sim`'s script
into OUT/state (on the study's path, geometric or rendered), the part type's feature plan written
there; the in-line service then runs the simulated line for a while (its warm-up, its in-line
recalibrations: the cell as it runs in production). Nothing is offset: the values are the cell's
as it reports them.

- type-1 study (`run_gauge`, on `inspection_cell`: the parameters in force and the U95 the
  service states after those windows, a view per feature planned on them): one master body
  clamped once and measured `repeats` times (each a new stop of the robot at every view, new
  sensor noise); per characteristic the bias against the master's truth, the repeatability s,
  Cg = 0.2 T / (6 s), Cgk = (0.1 T - |bias|) / (3 s), T the tolerance's width.
- correlation (`run_correlation`): the values the service itself stored for the bodies it
  measured in the cycle (app.line.body_cycle), one a clamp period, against their truth (the
  simulated CMM): per characteristic the mean and sd of in-line - truth, the share of values
  whose |in-line - truth| is within their U95, the median U95, RMS difference and R^2; and the
  decisions against the truth.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.api import Calibration
from app.config import CellConfig, load_cell
from app.errors import RvisError
from app.formats.files import read_json
from app.inspect.measure import BodyResult, measure_body
from app.inspect.plan import Characteristic, FeaturePlan, load_features
from app.inspect.values import StopNoise
from app.inspect.views import InspectionPlan, plan_views
from app.line.estimate import sphere_sigma_mm
from app.line.launch import hold_state
from app.line.schedule import Schedule
from app.line.settings import from_cell
from app.line.statedir import StateDir
from app.line.store import Store
from app.sim.bodies import SimulatedBodies, true_value
from app.sim.cell import make_cell
from app.sim.commissioned import commission_simulated
from app.sim.line_run import SimulatedLineRun
from app.sim.line_setup import world_of
from app.sim.part import ensure_features, nominal_features
from fakes.body import BodyShop, BuildProcess, ClampSettings
from fakes.cell import SimulatedCell
from vision.sensor_model import load_sensor_model

Progress = Callable[[str], None]


@dataclass
class InspectionCell:
    """A commissioned simulated cell ready to measure bodies: the parameters in force, the
    cell's statement for a point measured now, the world's temperature (None: the reference)."""

    seed: int
    state: StateDir
    cfg: CellConfig
    cal: Calibration
    plan: FeaturePlan
    views: InspectionPlan
    statement_u95_mm: float
    bodies: SimulatedBodies
    sigma_mm: float  # a sphere measurement's own noise, the statement's (sphere_sigma_mm)
    temp_c: float | None = None
    line: dict[str, Any] = field(default_factory=dict)

    def measure(self) -> BodyResult:
        """The body clamped now (`bodies.clamp`) measured along the route."""
        return measure_body(
            str(self.bodies.body.index if self.bodies.body else "-"),
            self.cal,
            self.plan,
            self.views,
            self.bodies,
            self.statement_u95_mm,
            self.temp_c,
            StopNoise(
                self.cfg.robot.repeatability_mm,
                self.sigma_mm,
                self.cfg.sensor.edge_u_mm,
                self.cfg.sensor.edge_u_slot_mm,
            ),
        )


def _commissioned(
    cfg: CellConfig, seed: int, out: Path, geometric: bool
) -> tuple[StateDir, CellConfig, FeaturePlan]:
    """The seed's simulated cell commissioned in out/state (a new folder) with the simulated
    part type's feature plan there, on the geometric or the rendered path (the rendered one
    identifies the hand-eye on spheres measured through the calibrated sensor model, which the
    bodies are measured through too)."""
    state = StateDir(out / "state")
    commission_simulated(cfg, state, seed, geometric)
    cfg_c = load_cell(state.cell)
    return state, cfg_c, load_features(ensure_features(state.root, cfg_c), cfg_c.T_part_base)


@contextmanager
def line_of(
    cfg: CellConfig, state: StateDir, seed: int, geometric: bool, *, bodies: bool
) -> Iterator[SimulatedLineRun]:
    """The in-line service on the state directory's simulated line (continuing its world), on
    the geometric or the rendered path (the rendered one measures with the commissioned sensor
    model), measuring the clamped bodies or not (the PLC without the body phase)."""
    if not bodies:
        cfg = dataclasses.replace(cfg, simline=dataclasses.replace(cfg.simline, body_s=0.0))
    model = None if geometric else load_sensor_model(state.sensor)
    with (
        hold_state(state.root, str(cfg.service.operators_group)),
        SimulatedLineRun(
            cfg, state.root, seed=seed, geometric=geometric, plan=state.plan, sensor_model=model
        ) as run,
    ):
        yield run


@contextmanager
def inspection_cell(
    cfg: CellConfig,
    seed: int,
    out: Path,
    line_windows: int = 0,
    process: BuildProcess | None = None,
    geometric: bool = True,
) -> Iterator[InspectionCell]:
    """The seed's simulated cell commissioned in out/state (a new folder), its part type's
    plan and views (module docstring). line_windows > 0: the in-line service first runs that
    many windows of the simulated line (its warm-up, its in-line recalibrations; no body), and
    the bodies are measured in that world, then, with the parameters in force and the U95 the
    service stated for its last window; 0: the commissioning's parameters and workspace U95 in
    the cold, still cell the commissioning measured. geometric False: the rendered path, the
    line's spheres and the bodies' sweeps alike, through the commissioned sensor model."""
    state, cfg_c, plan = _commissioned(cfg, seed, out, geometric)
    process = process or BuildProcess(seed=seed)
    sensor_model = load_sensor_model(state.sensor)
    vision = None if geometric else sensor_model

    def ready(world: SimulatedCell, statement: float, temp: float | None) -> InspectionCell:
        cal = Calibration.load(state.current)
        line, rp = cfg_c.line, cfg_c.robot.repeatability_mm
        views = plan_views(line, rp, cal.model, cal.x, plan, sensor_model)
        bodies = SimulatedBodies(world, plan, process, ClampSettings(), vision)
        schedule = Schedule.from_plan(state.plan, line)
        sigma = sphere_sigma_mm(from_cell(cfg_c), cal.model, cal.x, schedule, cfg_c.spheres_part_mm)
        return InspectionCell(seed, state, cfg_c, cal, plan, views, statement, bodies, sigma, temp)

    if line_windows == 0:
        doc = read_json(state.commission_report.with_suffix(".json"))
        yield ready(make_cell(world_of(cfg_c, state.root), seed=seed), _workspace_u95(doc), None)
        return
    with line_of(cfg_c, state, seed, geometric, bodies=False) as sim:
        summary = sim.run_windows(line_windows)
        stated = [r.u95_mm for r in summary.records if r.u95_mm is not None]
        if not stated:
            raise RvisError(f"the service stated no U95 in {line_windows} windows")
        cell = ready(sim.cell, stated[-1], sim.cell.temp_c)
        last = summary.records[-1]
        cell.line = {
            "windows": summary.windows,
            "version": last.version,
            "true_rmse_mm": last.rmse_mm,
            "temp_c": last.temp_c,
            "alarms": summary.alarms,
        }
        yield cell


def _workspace_u95(doc: dict[str, Any]) -> float:
    for s in doc.get("steps", []):
        if s.get("name") == "workspace":
            return float(s["results"]["u95_mm"])
    raise RvisError("the commissioning report has no workspace validation")


def run_gauge(
    cell: InspectionCell, repeats: int, progress: Progress | None = None
) -> dict[str, Any]:
    """The type-1 study (module docstring) on body 0, clamped once."""
    master = cell.bodies.clamp(0)
    by_key: dict[str, list[float]] = {}
    for r in range(repeats):
        result = cell.measure()
        for v in result.values:
            if v.measured_mm is not None:
                by_key.setdefault(v.characteristic.key, []).append(v.measured_mm)
        if progress and (r + 1) % 10 == 0:
            progress(f"repeat {r + 1}/{repeats}")
    rows = []
    for c in cell.plan.characteristics():
        vals = by_key.get(c.key, [])
        truth = true_value(master, c, cell.plan)
        row = _head(c) | {"n": len(vals), "true_mm": truth}
        if len(vals) >= 2:
            s = statistics.stdev(vals)
            bias = statistics.fmean(vals) - truth
            width = c.tol_mm[1] - c.tol_mm[0]
            row |= {
                "bias_mm": bias,
                "s_mm": s,
                "cg": 0.2 * width / (6 * s) if s > 0 else math.inf,
                "cgk": (0.1 * width - abs(bias)) / (3 * s) if s > 0 else math.inf,
            }
        rows.append(row)
    return {
        "seed": cell.seed,
        "repeats": repeats,
        "statement_u95_mm": cell.statement_u95_mm,
        "route_s": cell.views.route_s,
        "line": cell.line,
        "characteristics": rows,
        "summary": _gauge_summary(rows),
    }


def _head(c: Characteristic) -> dict[str, Any]:
    return {
        "feature": c.feature,
        "characteristic": c.name,
        "kind": c.kind,
        "tolerance_mm": list(c.tol_mm),
    }


def _gauge_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    pos = [r for r in rows if r["kind"] == "position" and "cg" in r]
    size = [r for r in rows if r["kind"] == "size" and "cg" in r]
    return {
        "position": len(pos),
        "position_cg_at_least_1_33": sum(r["cg"] >= 1.33 for r in pos),
        "position_cgk_at_least_1_33": sum(r["cgk"] >= 1.33 for r in pos),
        "size": len(size),
        "size_cg_at_least_1_33": sum(r["cg"] >= 1.33 for r in size),
        "size_cgk_at_least_1_33": sum(r["cgk"] >= 1.33 for r in size),
        "min_cg": min((r["cg"] for r in pos), default=None),
        "median_s_mm": statistics.median(r["s_mm"] for r in pos) if pos else None,
    }


@dataclass(frozen=True)
class LineStudy:
    """The correlation's line: `line_windows` windows with no body (the warm-up and the first
    in-line recalibrations), then a body in each of the next `bodies` clamp periods; a knock
    of `knock_kind` at `knock_at_h` hours of the line's time (None: none); the geometric or the
    rendered path."""

    bodies: int = 50
    line_windows: int = 120
    knock_kind: str | None = None
    knock_at_h: float = 1.0
    geometric: bool = True


def run_correlation(
    cfg: CellConfig, seed: int, out: Path, study: LineStudy, progress: Progress | None = None
) -> dict[str, Any]:
    """In-line against the simulated CMM (module docstring): the cell commissioned into
    out/state with the part type, the in-line service run on the simulated line measuring a
    body in every clamp period (app.line.body_cycle), and the values it stored (each body's
    newest evaluation: as measured, or computed again after a corrected knock) against the
    bodies' truth."""
    state, cfg_c, plan = _commissioned(cfg, seed, out, study.geometric)
    if study.knock_kind is not None:
        simline = dataclasses.replace(
            cfg_c.simline, knock_at_s=3600.0 * study.knock_at_h, knock_kind=study.knock_kind
        )
        cfg_c = dataclasses.replace(cfg_c, simline=simline)

    def told(record: Any) -> None:
        if progress and record.window % 20 == 0:
            progress(f"window {record.window}")

    alarms: list[str] = []
    if study.line_windows:  # the warm-up and the first recalibrations, no body measured
        with line_of(cfg_c, state, seed, study.geometric, bodies=False) as run:
            alarms += run.run_windows(study.line_windows, on_window=told).alarms
    with line_of(cfg_c, state, seed, study.geometric, bodies=True) as run:
        summary = run.run_windows(study.bodies, on_window=told)
        first_body = run.line.settings.first_body
    alarms += summary.alarms
    shop = BodyShop(nominal_features(plan), BuildProcess(seed=seed))
    store = Store.read_only(state.db)
    try:
        measured = store.bodies()[: study.bodies]
        pairs, not_measured = _pairs(store, plan, shop, measured, first_body)
        reevaluated = _reevaluated(store, plan, shop, first_body) if study.knock_kind else None
        suspects = store.suspects()
        counted = {b["body_id"] for b in measured}
        robot_s = [
            float(e["data"]["robot_s"])
            for e in store.events("body")
            if e["data"].get("body_id") in counted and not e["data"].get("withdrawn")
        ]
    finally:
        store.close()
    rows = [_correlation_row(c, pairs.get(c.key, [])) for c in plan.characteristics()]
    doc: dict[str, Any] = {
        "seed": seed,
        "bodies": len(measured),
        "line": {
            "windows": study.line_windows + summary.windows, "alarms": alarms,
            "path": "geometric" if study.geometric else "rendered",
            "versions": sorted({b["params_version"] for b in measured}),
            "knock": None if study.knock_kind is None
            else {"kind": study.knock_kind, "at_h": study.knock_at_h},
            "suspect_intervals": len(suspects),
            # the robot's time a body took in the simulation (out of home and back)
            "robot_s_per_body": statistics.median(robot_s) if robot_s else None,
            "robot_s_per_feature": statistics.median(robot_s) / len(plan.features)
            if robot_s else None,
        },
        "characteristics": rows,
        "decisions": _decisions(plan, pairs),
        "not_measured": not_measured,
        "summary": _correlation_summary(rows, pairs),
    }  # fmt: skip
    if reevaluated is not None:
        doc["reevaluated"] = reevaluated
    return doc


Pair = tuple[float, float, float, str]


def _pairs(
    store: Store, plan: FeaturePlan, shop: BodyShop, bodies: list[dict[str, Any]], first: int
) -> tuple[dict[str, list[Pair]], dict[str, int]]:
    """(measured, truth, U95, decision) per characteristic key over the bodies' newest values,
    and how often each was not measured."""
    pairs: dict[str, list[Pair]] = {}
    not_measured: dict[str, int] = {}
    for b in bodies:
        truth = shop.body(int(b["body_id"]) - first)
        for v, c in zip(store.body_values(int(b["id"])), plan.characteristics(), strict=True):
            if v["measured_mm"] is None or v["u95_mm"] is None:
                not_measured[c.key] = not_measured.get(c.key, 0) + 1
                continue
            t = true_value(truth, c, plan)
            pairs.setdefault(c.key, []).append((v["measured_mm"], t, v["u95_mm"], v["decision"]))
    return pairs, not_measured


def _reevaluated(store: Store, plan: FeaturePlan, shop: BodyShop, first: int) -> dict[str, Any]:
    """The bodies computed again after a corrected step: how many values, and their RMS
    difference to the truth as measured and as computed again (position characteristics)."""
    before: list[float] = []
    after: list[float] = []
    bodies = [b for b in store.bodies() if b["evaluation"] > 0]
    for b in bodies:
        truth = shop.body(int(b["body_id"]) - first)
        for k, out in ((0, before), (int(b["evaluation"]), after)):
            for v, c in zip(
                store.body_values(int(b["id"]), k), plan.characteristics(), strict=True
            ):
                if c.kind == "position" and v["measured_mm"] is not None:
                    out.append(v["measured_mm"] - true_value(truth, c, plan))
    intervals = [s for s in store.suspects() if s.get("reevaluated") is not None]
    return {
        "bodies": len(bodies),
        "values": len(after),
        "not_reevaluated_bodies": sum(int(s.get("not_reevaluated") or 0) for s in intervals),
        "decisions_changed": sum(int(s.get("decisions_changed") or 0) for s in intervals),
        "rms_diff_before_mm": _rms(before),
        "rms_diff_after_mm": _rms(after),
    }


def _rms(values: list[float]) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if values else None


def _correlation_row(
    c: Characteristic, pairs: list[tuple[float, float, float, str]]
) -> dict[str, Any]:
    row = _head(c) | {"n": len(pairs)}
    if len(pairs) < 2:
        return row
    m, t, u = (np.array([p[i] for p in pairs]) for i in range(3))
    d = m - t
    r2 = float(np.corrcoef(m, t)[0, 1] ** 2) if np.std(t) > 0 and np.std(m) > 0 else None
    return row | {
        "mean_diff_mm": float(d.mean()),
        "sd_diff_mm": float(d.std(ddof=1)),
        "coverage": float(np.mean(np.abs(d) <= u)),
        "u95_median_mm": float(np.median(u)),
        "rms_diff_mm": float(np.sqrt(np.mean(d**2))),
        "r2": r2,
    }


def _decisions(
    plan: FeaturePlan, pairs: dict[str, list[tuple[float, float, float, str]]]
) -> dict[str, int]:
    """nok_true: values truly outside their tolerance by more than twice their U95; nok_found:
    of those, decided nonconforming; ok_true: truly inside by more than their U95; nok_false:
    of those, decided nonconforming."""
    out = {"nok_true": 0, "nok_found": 0, "ok_true": 0, "nok_false": 0}
    for c in plan.characteristics():
        lo, hi = c.limits_mm
        for _, truth, u, decision in pairs.get(c.key, []):
            outside = max(lo - truth, truth - hi)
            if outside > 2 * u:
                out["nok_true"] += 1
                out["nok_found"] += decision == "nonconforming"
            elif -outside > u:
                out["ok_true"] += 1
                out["nok_false"] += decision == "nonconforming"
    return out


def _correlation_summary(
    rows: list[dict[str, Any]], pairs: dict[str, list[tuple[float, float, float, str]]]
) -> dict[str, Any]:
    pos = [r for r in rows if r["kind"] == "position" and "mean_diff_mm" in r]
    every = [p for ps in pairs.values() for p in ps]
    d = np.array([p[0] - p[1] for p in every])
    u = np.array([p[2] for p in every])
    return {
        "values": len(every),
        "position": len(pos),
        "position_mean_within_0_05": sum(abs(r["mean_diff_mm"]) <= 0.05 for r in pos),
        "position_mean_within_0_10": sum(abs(r["mean_diff_mm"]) <= 0.10 for r in pos),
        "max_abs_mean_diff_mm": max((abs(r["mean_diff_mm"]) for r in pos), default=None),
        "max_sd_diff_mm": max((r["sd_diff_mm"] for r in rows if "sd_diff_mm" in r), default=None),
        "coverage": float(np.mean(np.abs(d) <= u)) if len(d) else None,
        "u95_median_over_rms": _ratio(d, u),
        "by_kind": {kind: _by_kind(rows, pairs, kind) for kind in ("position", "size")},
    }


def _ratio(d: np.ndarray, u: np.ndarray) -> float | None:
    rms = float(np.sqrt(np.mean(d**2))) if len(d) else 0.0
    return float(np.median(u)) / rms if rms > 0 else None


def _by_kind(
    rows: list[dict[str, Any]], pairs: dict[str, list[tuple[float, float, float, str]]], kind: str
) -> dict[str, Any]:
    keys = {f"{r['feature']}.{r['characteristic']}" for r in rows if r["kind"] == kind}
    every = [p for k in keys for p in pairs.get(k, [])]
    d = np.array([p[0] - p[1] for p in every])
    u = np.array([p[2] for p in every])
    return {
        "values": len(every),
        "coverage": float(np.mean(np.abs(d) <= u)) if len(d) else None,
        "rms_diff_mm": float(np.sqrt(np.mean(d**2))) if len(d) else None,
        "u95_median_mm": float(np.median(u)) if len(u) else None,
        "u95_median_over_rms": _ratio(d, u),
    }
