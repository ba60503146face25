"""The commissioning steps that move the robot and measure spheres: the first calibration from
the planned configurations, and its validation against the tracker's sphere positions from
views the calibration has not seen. Every configuration is reached from home and left back
home, as the service will do between clamping cycles; every motion is confirmed (Context.move).
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
    VALIDATION_ERRORS_FILE,
    VALIDATION_MEASUREMENTS_FILE,
)
from app.config import CellConfig
from app.formats.files import (
    ERROR_COLUMNS,
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


def calibration_views(
    cell: CellConfig, planned: dict[str, F64], positions: dict[str, F64]
) -> list[tuple[str, F64]]:
    """The calibration step's views: each sphere's planned configurations, then random views
    of it (calib.candidates, on the nominal model, seeded by [commission] seed) up to
    `[commission] calibration_views_per_sphere`."""
    rigid = cell.model()
    rng = np.random.default_rng([cell.commission.seed, 29])
    want = cell.commission.calibration_views_per_sphere
    views = []
    for target, q_list in planned.items():
        views += [(target, q) for q in q_list]
        more = want - len(q_list)
        if more > 0 and target in positions:
            sample = candidates.random_configurations(
                rigid, rigid.nominal_x(), positions[target], more, rng
            )
            views += [(target, q) for q in sample.q_deg]
    return views


def calibration(ctx: Context) -> StepResult:
    """Measure the plan's configurations and random views beyond them (`calibration_views`),
    identify the commissioning's model (CellConfig.commissioning_model), and hold it to the
    quality gates of [calibration] (converged, rank, RMS, condition, change from nominal)."""
    cell = ctx.cell()
    _, qs, _ = read_plan(ctx.path(PLAN_FILE))
    positions = ctx.spheres_part_mm()
    views = calibration_views(cell, qs, positions)
    taken = measure_views(ctx, views, ctx.sphere_sensor(ctx.sensor_model()), "calibration")
    taken.write(ctx.path(CALIBRATION_MEASUREMENTS_FILE))
    write_targets(ctx.path(CALIBRATION_TARGETS_FILE), positions)
    r = StepResult(files=[CALIBRATION_MEASUREMENTS_FILE, CALIBRATION_TARGETS_FILE])
    limit = cell.commission.max_rejected_fraction
    r.checks.append(
        share_at_most("views rejected by vision", len(taken.rejected), len(views), limit)
    )
    r.results["rejected"] = taken.rejected
    model = cell.commissioning_model()
    try:
        result = identify(model, taken.data(positions))
    except InsufficientData as exc:
        r.checks.append(holds("identification", False, str(exc)))
        return r
    report = check_identification(result, model.nominal_x(), cell.calibration.gates())
    doc = to_json(model, result, report, provenance())
    write_json(ctx.path(PARAMS_FILE if report.passed else PARAMS_REJECTED_FILE), doc)
    r.files.append(PARAMS_FILE if report.passed else PARAMS_REJECTED_FILE)
    g = cell.calibration
    r.results |= {
        "measurements": len(taken.targets),
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
