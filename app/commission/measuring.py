"""The commissioning steps that move the robot and measure spheres: the pre-calibration from
random views (the paper's section 4.1: the model the plan is made on), the first calibration
from the planned configurations and those random views, and its validation against the
tracker's sphere positions from views the calibration has not seen. Every configuration is
reached from home and left back home, as the service will do between clamping cycles; every
motion is confirmed (Context.move).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.checks import (
    StepResult,
    at_most,
    count_at_least,
    holds,
    ratio_at_most,
    share_at_most,
)
from app.commission.context import Context
from app.commission.files import (
    CALIBRATION_MEASUREMENTS_FILE,
    CALIBRATION_TARGETS_FILE,
    PARAMS_FILE,
    PARAMS_REJECTED_FILE,
    PLAN_FILE,
    PRECALIBRATION_MEASUREMENTS_FILE,
    PRECALIBRATION_PARAMS_FILE,
    VALIDATION_ERRORS_FILE,
    VALIDATION_MEASUREMENTS_FILE,
)
from app.config import CellConfig
from app.formats.files import (
    ERROR_COLUMNS,
    read_measurements,
    write_csv,
    write_json,
    write_measurements,
    write_targets,
)
from app.formats.params import from_json, to_json
from app.line.cycle import cell_temperature
from app.line.measure import Rejected, SphereSensor
from app.meta import provenance
from app.planning import read_plan
from calib import candidates
from calib.errors import InsufficientData
from calib.gates import check_identification
from calib.identify import Measurements, identify
from calib.validation import rmse

F64 = NDArray[np.float64]


@dataclass
class Taken:
    """The measurements of a run of views (and the views the vision rejected)."""

    targets: list[str] = field(default_factory=list)
    q_deg: list[F64] = field(default_factory=list)
    c_sensor_mm: list[F64] = field(default_factory=list)
    temp_c: list[float | None] = field(default_factory=list)
    rejected: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # why a cell temperature was missing
    quality: list[dict[str, Any]] = field(default_factory=list)  # each reading's fit figures

    def data(self, positions: dict[str, F64]) -> Measurements:
        temps = None if any(t is None for t in self.temp_c) else np.array(self.temp_c)
        return Measurements(
            np.array(self.q_deg).reshape(-1, 6),
            np.array(self.c_sensor_mm).reshape(-1, 3),
            np.array([positions[t] for t in self.targets]).reshape(-1, 3),
            tuple(self.targets),
            temps,
        )

    def extend(self, other: Taken) -> None:
        """`other`'s measurements after these (its rejections and notes are its own)."""
        self.targets += other.targets
        self.q_deg += other.q_deg
        self.c_sensor_mm += other.c_sensor_mm
        self.temp_c += other.temp_c

    def write(self, path: object) -> None:
        temps = None if any(t is None for t in self.temp_c) else np.array(self.temp_c)
        q, c = np.array(self.q_deg).reshape(-1, 6), np.array(self.c_sensor_mm).reshape(-1, 3)
        write_measurements(path, self.targets, q, c, temps)  # type: ignore[arg-type]


def measure_views(
    ctx: Context,
    views: list[tuple[str, F64]],
    sensor: SphereSensor,
    what: str,
    *,
    via_home: bool = True,
    end_home: bool = True,
) -> Taken:
    """Each (sphere, q_deg) from home and back home (`via_home`; else from view to view, home
    at the end: the line stopped for maintenance has no clamping cycle to clear); the PLC's
    cell temperature with each (when the cell file says the PLC provides it, and plausible:
    app.line.cycle.cell_temperature). With `via_home` a robot left away from home (a
    commissioning killed mid-step) goes home first; `end_home` False leaves it at the last
    view (a caller that measures more views next and goes home itself)."""
    taken = Taken()
    if via_home:
        ctx.home()
    for k, (target, q) in enumerate(views, start=1):
        ctx.move(q, f"{what} view {k}/{len(views)} (sphere {target})")
        ctx.robot_s += ctx.sweep.duration_s  # the robot stands still for the sweep
        try:
            reading = sensor.measure(target)
        except Rejected as exc:
            taken.rejected.append(f"{target} view {k}: {exc}")
            ctx.say(f"    view {k}: rejected by the vision checks ({exc})")
        else:
            taken.targets.append(target)
            taken.q_deg.append(np.asarray(q, dtype=float))
            taken.c_sensor_mm.append(reading.c_sensor_mm)
            taken.quality.append(reading.quality)
            temp_c, why = cell_temperature(ctx.station.plc.poll(), ctx.line)
            if why and why not in taken.notes:
                taken.notes.append(why)
                ctx.say(f"    no cell temperature: {why}")
            taken.temp_c.append(temp_c)
        if via_home:
            ctx.home()
    if end_home:
        ctx.home()
    return taken


def precalibration_views_per_sphere(cell: CellConfig) -> int:
    """The pre-calibration's random views a sphere: those the first calibration takes beyond
    the plan's (`[commission] calibration_views_per_sphere` less `[calibration]
    configs_per_sphere`), and at least as many as the plan's (the paper's 6 random views a
    sphere, section 5.1)."""
    n_plan = cell.calibration.configs_per_sphere
    return max(cell.commission.calibration_views_per_sphere - n_plan, n_plan)


def precalibration_views(cell: CellConfig, positions: dict[str, F64]) -> list[tuple[str, F64]]:
    """The pre-calibration's views: `precalibration_views_per_sphere` random views of each
    sphere (calib.candidates on the nominal model, seeded by [commission] seed)."""
    rigid = cell.model()
    rng = np.random.default_rng([cell.commission.seed, 29])
    n = precalibration_views_per_sphere(cell)
    views = []
    for target, p in positions.items():
        sample = candidates.random_configurations(rigid, rigid.nominal_x(), p, n, rng)
        views += [(target, q) for q in sample.q_deg]
    return views


def _identified(
    ctx: Context,
    cell: CellConfig,
    r: StepResult,
    data: Measurements,
    passed_file: str,
    rejected_file: str | None,
) -> None:
    """Identify the commissioning's model (CellConfig.commissioning_model) from `data`, hold
    it to the quality gates of [calibration] and write it to `passed_file` when it passed,
    else to `rejected_file` (None: not written); its figures and checks into `r`."""
    model = cell.commissioning_model()
    try:
        result = identify(model, data)
    except InsufficientData as exc:
        r.checks.append(holds("identification", False, str(exc)))
        return
    report = check_identification(result, model.nominal_x(), cell.calibration.gates())
    doc = to_json(model, result, report, provenance())
    name = passed_file if report.passed else rejected_file
    if name is not None:
        write_json(ctx.path(name), doc)
        r.files.append(name)
    g = cell.calibration
    r.results |= {
        "measurements": len(data),
        "rms_mm": result.rms_mm,
        "max_mm": result.max_mm,
        "rank": result.observability.rank,
        "condition": result.observability.condition,
        "gates": report.reason or "passed",
    }
    r.checks += [
        at_most("residual RMS", result.rms_mm, g.max_rms_mm, "mm"),
        at_most("condition", result.observability.condition, g.max_condition),
        holds("quality gates", report.passed, report.reason or "passed"),
    ]


def _rejected_check(cell: CellConfig, r: StepResult, taken: Taken, n_views: int) -> None:
    limit = cell.commission.max_rejected_fraction
    r.checks.append(share_at_most("views rejected by vision", len(taken.rejected), n_views, limit))
    r.results |= {"views": n_views, "rejected": taken.rejected}


def precalibration(ctx: Context) -> StepResult:
    """The paper's pre-calibration (section 4.1): random views of every sphere
    (`precalibration_views`), the commissioning's model identified from them and held to the
    quality gates of [calibration]: the hand-eye and the base the plan's inverse kinematics
    needs, so that the planned views see their sphere on the cell as built. Its views are
    the first calibration's random ones."""
    cell = ctx.cell()
    positions = ctx.spheres_part_mm()
    views = precalibration_views(cell, positions)
    sensor = ctx.sphere_sensor(ctx.sensor_model())
    taken = measure_views(ctx, views, sensor, "pre-calibration")
    taken.write(ctx.path(PRECALIBRATION_MEASUREMENTS_FILE))
    r = StepResult(files=[PRECALIBRATION_MEASUREMENTS_FILE])
    _rejected_check(cell, r, taken, len(views))
    _identified(ctx, cell, r, taken.data(positions), PRECALIBRATION_PARAMS_FILE, None)
    return r


def precalibrated_x(ctx: Context) -> F64:
    """The pre-calibration's parameters of the rigid model (the plan's IK needs no more)."""
    _, x = from_json(ctx.path(PRECALIBRATION_PARAMS_FILE))
    return x[: len(ctx.cell().model().nominal_x())]


def _precalibration_taken(ctx: Context, cell: CellConfig, planned: dict[str, F64]) -> Taken:
    """The pre-calibration's measurements the first calibration takes beyond the plan's:
    `[commission] calibration_views_per_sphere` a sphere with the plan's (0: none)."""
    rows = read_measurements(ctx.path(PRECALIBRATION_MEASUREMENTS_FILE))
    want = cell.commission.calibration_views_per_sphere
    temps = [None] * len(rows.targets) if rows.temp_c is None else list(map(float, rows.temp_c))
    taken = Taken()
    count: dict[str, int] = {}
    for k, target in enumerate(rows.targets):
        room = want - len(planned.get(target, ())) if want > 0 else 0
        if count.get(target, 0) >= room:
            continue
        count[target] = count.get(target, 0) + 1
        taken.targets.append(target)
        taken.q_deg.append(rows.q_deg[k])
        taken.c_sensor_mm.append(rows.c_sensor_mm[k])
        taken.temp_c.append(temps[k])
    return taken


def calibration(ctx: Context) -> StepResult:
    """Measure the plan's configurations, identify the commissioning's model
    (CellConfig.commissioning_model) from them and the pre-calibration's random views
    (`_precalibration_taken`), and hold it to the quality gates of [calibration] (converged,
    rank, RMS, condition, change from nominal)."""
    cell = ctx.cell()
    _, qs, _ = read_plan(ctx.path(PLAN_FILE))
    positions = ctx.spheres_part_mm()
    views = [(target, q) for target, q_list in qs.items() for q in q_list]
    taken = measure_views(ctx, views, ctx.sphere_sensor(ctx.sensor_model()), "calibration")
    r = StepResult(files=[CALIBRATION_MEASUREMENTS_FILE, CALIBRATION_TARGETS_FILE])
    _rejected_check(cell, r, taken, len(views))
    taken.extend(_precalibration_taken(ctx, cell, qs))
    taken.write(ctx.path(CALIBRATION_MEASUREMENTS_FILE))
    write_targets(ctx.path(CALIBRATION_TARGETS_FILE), positions)
    _identified(ctx, cell, r, taken.data(positions), PARAMS_FILE, PARAMS_REJECTED_FILE)
    return r


def validation(ctx: Context) -> StepResult:
    """Measure every sphere from `[commission] validation_views` new views (planned on the
    identified model) and compare the positions the calibrated system computes with the
    tracker's: the RMS error within its limit and below the nominal model's."""
    cell = ctx.cell()
    model, x = from_json(ctx.path(PARAMS_FILE))
    rigid = cell.model()
    x_rigid = x[: len(rigid.nominal_x())]
    positions = ctx.spheres_part_mm()
    rng = np.random.default_rng([cell.commission.seed, 23])
    views = []
    for target, p in positions.items():
        sample = candidates.random_configurations(
            rigid, x_rigid, p, cell.commission.validation_views, rng
        )
        views += [(target, q) for q in sample.q_deg]
    sensor_model = ctx.sensor_model()
    taken = measure_views(ctx, views, ctx.sphere_sensor(sensor_model), "validation")
    taken.write(ctx.path(VALIDATION_MEASUREMENTS_FILE))
    r = StepResult(files=[VALIDATION_MEASUREMENTS_FILE, VALIDATION_ERRORS_FILE])
    data = taken.data(positions)
    p_id = model.points_part(x, data.q_deg, data.c_sensor_mm, temp_c=data.temp_c)
    p_nom = model.points_part(model.nominal_x(), data.q_deg, data.c_sensor_mm, temp_c=data.temp_c)
    e_id, e_nom = p_id - data.p_part_mm, p_nom - data.p_part_mm
    d = np.linalg.norm(e_id, axis=1)
    rows = [
        [t, *map(float, p_id[i]), *map(float, e_id[i]), float(d[i])]
        for i, t in enumerate(data.targets)
    ]
    write_csv(ctx.path(VALIDATION_ERRORS_FILE), ERROR_COLUMNS, rows)
    error_mm = rmse(e_id) if len(d) else float("inf")
    nominal_mm = rmse(e_nom) if len(d) else float("inf")
    r.results = {
        "views": len(views),
        "measured": len(data),
        "rmse_mm": error_mm,
        "max_mm": float(d.max()) if len(d) else float("inf"),
        "rmse_nominal_mm": nominal_mm,
        "rejected": taken.rejected,
    }
    if ctx.truth is not None:
        # simulated line only: the end-to-end error over the workspace (app/sim/truth.py)
        r.results["true_rmse_mm"] = ctx.truth.true_rmse_mm(model, x, sensor_model)
    r.checks += [
        count_at_least(
            "spheres measured",
            len(data),
            len(views),
            len(views) * (1 - cell.commission.max_rejected_fraction),
        ),
        at_most("validation RMSE", error_mm, cell.commission.max_validation_rmse_mm, "mm"),
        ratio_at_most("validation RMSE, calibrated / nominal", error_mm, nominal_mm, unit="mm"),
    ]
    return r
