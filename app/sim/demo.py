"""The demo: the simulated cell end to end (simulate, identify, validate, report).

Besides the before/after table it splits what remains after calibration: the error of the
identified parameters alone (noise-free evaluation against the truth), the part that the
unmodelled joint compliance causes (identification on noise-free data), and the part that
measurement noise causes (identification on the same noise with a rigid robot).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.formats.files import write_json, write_measurements, write_targets, write_text
from app.formats.params import to_json
from app.formats.report import (
    PARAM_HEADER,
    STATS_HEADER,
    markdown_table,
    parameter_rows,
    plot_errors,
    stats_rows,
    text_table,
)
from app.line.statedir import PLAN_NAME
from app.meta import provenance
from app.planning import plan_to_json, run_plan
from app.sim.cell import (
    DataSet,
    GeometricMeasurement,
    Measurement,
    collect,
    make_cell,
    measurement_report,
    simulated_sets,
)
from calib.gates import GateReport, check_identification
from calib.identify import IdentificationResult, Measurements, identify, residuals
from calib.model import SystemModel
from calib.plan_settings import Plan, Progress
from calib.validation import ErrorStats, rmse
from fakes.cell import SimulatedCell

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class PlannedRun:
    """Calibration with the planned configurations (and positions) on the same cell."""

    plan: Plan
    data: DataSet
    result: IdentificationResult
    placement: str


@dataclass(frozen=True)
class DemoResult:
    stats: dict[str, ErrorStats]
    breakdown_mm: dict[str, float]
    result: IdentificationResult
    run_dir: Path
    seconds: float
    cfg: CellConfig
    measurement: dict[str, Any] = field(default_factory=dict)
    planned: PlannedRun | None = None
    seed: int = 0

    def gates(self, result: IdentificationResult) -> GateReport:
        """The cell's quality gates of an identification of this run (offline: vs nominal)."""
        return check_identification(
            result, self.cfg.model().nominal_x(), self.cfg.calibration.gates()
        )


def truth_set(ds: DataSet, c_sensor_mm: F64, with_noise: bool) -> Measurements:
    """The data set with true sensor centres (plus the original noise if with_noise)."""
    m = ds.measurements
    c = c_sensor_mm + (m.c_sensor_mm - ds.truth_c_sensor_mm if with_noise else 0.0)
    p = ds.truth_p_part_mm + (m.p_part_mm - ds.truth_p_part_mm if with_noise else 0.0)
    return Measurements(m.q_deg, c, p, m.targets)


def error_breakdown(
    cfg: CellConfig, seed: int, model: SystemModel, cal: DataSet, val: DataSet, x_id: F64
) -> dict[str, float]:
    """RMSE [mm] of: the identified parameters alone; compliance alone; noise alone."""
    val_truth = truth_set(val, val.truth_c_sensor_mm, with_noise=False)
    out = {"parameters_alone": rmse(residuals(model, x_id, val_truth))}
    clean = identify(model, truth_set(cal, cal.truth_c_sensor_mm, with_noise=False))
    out["compliance_alone"] = rmse(residuals(model, clean.x, val_truth))
    rigid = make_cell(cfg, seed=seed, compliance=False)
    m = cal.measurements
    c_rigid = np.array(
        [rigid.centre_in_sensor(q, p)[0] for q, p in zip(m.q_deg, cal.truth_p_part_mm, strict=True)]
    )
    noisy = identify(model, truth_set(cal, c_rigid, with_noise=True))
    v = val.measurements
    c_val_rigid = np.array(
        [rigid.centre_in_sensor(q, p)[0] for q, p in zip(v.q_deg, val.truth_p_part_mm, strict=True)]
    )
    val_rigid = Measurements(v.q_deg, c_val_rigid, val.truth_p_part_mm, v.targets)
    out["noise_alone"] = rmse(residuals(model, noisy.x, val_rigid))
    out["validation_measurement_noise"] = rmse(
        residuals(model, x_id, val.measurements) - residuals(model, x_id, val_truth)
    )
    return out


def run_demo(
    cfg: CellConfig,
    seed: int,
    run_dir: Path,
    n_validation: int = 100,
    placement: str | None = "fixed",
    progress: Progress | None = None,
    measurement: Measurement | None = None,
) -> DemoResult:
    """The demo. measurement: how sphere centres are measured (default: geometric; `rvis
    demo` renders). With `placement` (fixed, sequential, joint) it also plans on the
    pre-calibrated parameters and calibrates again with the planned configurations (None:
    random configurations only)."""
    t0 = time.perf_counter()
    sim = simulated_sets(cfg, seed, n_validation=n_validation, measurement=measurement)
    cell, model, rng, cal, val = sim.cell, sim.model, sim.rng, sim.calibration, sim.validation
    x0 = model.nominal_x()
    n_each = cfg.calibration.configs_per_sphere
    result = identify(model, cal.measurements, loss=str(cfg.calibration["loss"]))
    e_before = residuals(model, x0, val.measurements)
    e_after = residuals(model, result.x, val.measurements)
    stats = {"nominal": ErrorStats.of(e_before), "identified": ErrorStats.of(e_after)}
    # the split against the truth needs measurements in the true sensor frame: not with a
    # calibrated sensor model, whose small rigid error the hand-eye absorbs
    exact = getattr(measurement, "sensor_frame_exact", True)
    breakdown = error_breakdown(cfg, seed, model, cal, val, result.x) if exact else {}
    errors = {"nominal": e_before, "identified": e_after}
    planned = None
    sets = {"calibration": cal, "validation": val}
    if placement is not None:
        planned = planned_run(
            cfg, cell, model, result.x, placement, n_each, rng, progress, measurement
        )
        sets["planned"] = planned.data
        errors = {"nominal": e_before, "random configurations": e_after}
        errors["planned configurations"] = residuals(model, planned.result.x, val.measurements)
        stats["planned"] = ErrorStats.of(errors["planned configurations"])
    info = measurement_report(measurement or GeometricMeasurement(), sets)
    demo = DemoResult(
        stats, breakdown, result, run_dir, time.perf_counter() - t0, cfg, info, planned, seed
    )
    _write_run(demo, model, cal, val, errors)
    return demo


def planned_run(
    cfg: CellConfig,
    cell: SimulatedCell,
    model: SystemModel,
    x_pre: F64,
    placement: str,
    n_each: int,
    rng: np.random.Generator,
    progress: Progress | None = None,
    measurement: Measurement | None = None,
) -> PlannedRun:
    """Plan on the pre-calibrated parameters, move the spheres to the planned positions
    (tracker-measured), measure from the planned configurations, identify."""
    plan = run_plan(cfg, model, x_pre, placement=placement, progress=progress)
    data = collect(
        cell,
        model,
        x_pre,
        plan.positions_part_mm(),
        n_each,
        rng,
        q_by_target=plan.q_by_sphere(),
        measurement=measurement,
    )
    result = identify(model, data.measurements, loss=str(cfg.calibration["loss"]))
    return PlannedRun(plan, data, result, placement)


def _write_run(
    demo: DemoResult, model: SystemModel, cal: DataSet, val: DataSet, errors: dict[str, F64]
) -> None:
    d = demo.run_dir
    d.mkdir(parents=True, exist_ok=True)
    for name, ds in (("calibration", cal), ("validation", val)):
        m = ds.measurements
        write_measurements(d / f"{name}_measurements.csv", m.targets, m.q_deg, m.c_sensor_mm)
        write_targets(d / f"{name}_targets.csv", ds.targets)
    meta = provenance(demo.seed)
    write_json(d / "params.json", to_json(model, demo.result, demo.gates(demo.result), meta))
    pr = demo.planned
    if pr is not None:
        m = pr.data.measurements
        write_measurements(d / "planned_measurements.csv", m.targets, m.q_deg, m.c_sensor_mm)
        write_targets(d / "planned_targets.csv", pr.data.targets)
        write_json(
            d / "params_planned.json", to_json(model, pr.result, demo.gates(pr.result), meta)
        )
        plan_doc = plan_to_json(demo.cfg, model, demo.result.x, pr.plan)
        # named as a state directory names its plan: `rvis run --plan` or a copy to STATE_DIR
        write_json(d / PLAN_NAME, {**plan_doc, "provenance": meta})
    report: dict[str, Any] = {
        "provenance": meta,
        "quality_gates": demo.gates(demo.result).to_json(),
        "validation": {k: asdict(v) for k, v in demo.stats.items()},
        "improvement_factor": demo.stats["nominal"].rmse_mm / demo.stats["identified"].rmse_mm,
        "remaining_error_breakdown_rmse_mm": demo.breakdown_mm,
        "observability": demo.result.observability.indices,
        "rank": demo.result.observability.rank,
        "condition": demo.result.observability.condition,
        "seconds": demo.seconds,
        "measurement": demo.measurement,
    }
    if pr is not None:
        report["planned"] = {
            "placement": pr.placement,
            "n_measurements": len(pr.data.measurements),
            "observability": pr.result.observability.indices,
            "plan_observability": pr.plan.observability.indices,
            "rank": pr.result.observability.rank,
            "condition": pr.result.observability.condition,
            "rmse_reduction_vs_random": 1.0
            - demo.stats["planned"].rmse_mm / demo.stats["identified"].rmse_mm,
            "plan_seconds": pr.plan.seconds,
        }
    write_json(d / "report.json", report)
    plot_errors(d / "validation_errors.png", errors, "Validation errors at 100 positions")
    write_text(d / "report.md", markdown_report(demo, model, meta))


def summary_text(demo: DemoResult) -> str:
    s = demo.stats
    b = demo.breakdown_mm
    obs = demo.result.observability
    lines = [
        f"Validation at {s['identified'].n} positions (mm):",
        text_table(STATS_HEADER, stats_rows(s)),
        "",
        f"RMSE improved {s['nominal'].rmse_mm / s['identified'].rmse_mm:.1f}x.",
        (
            "What remains (RMSE, mm): identified parameters alone "
            f"{b['parameters_alone']:.4f}; of it, unmodelled compliance alone "
            f"{b['compliance_alone']:.4f} and measurement noise alone {b['noise_alone']:.4f}; the "
            f"validation measurements' own noise adds {b['validation_measurement_noise']:.4f}."
            if b
            else "What remains: the split into parameter, compliance and noise parts compares "
            "with the true sensor frame, which a calibrated sensor model only approximates "
            "(its rigid error goes into the hand-eye); run with --geometric or --sensor-model "
            "truth for it."
        ),
        f"Identification: {len(demo.result.residuals_mm)} measurements, rank {obs.rank}, "
        f"condition {obs.condition:.1f}, "
        + ", ".join(f"{k} {v:.4g}" for k, v in obs.indices.items()),
        *measurement_lines(demo.measurement),
    ]
    pr = demo.planned
    if pr is not None:
        where = {
            "fixed": "spheres where the cell has them",
            "sequential": "spheres placed one by one (PSO)",
            "joint": "spheres placed jointly (PSO)",
        }[pr.placement]
        o_r, o_p = obs.indices["O1"], pr.result.observability.indices["O1"]
        r_r, r_p = s["identified"].rmse_mm, s["planned"].rmse_mm
        lines += [
            "",
            f"Planned configurations ({where}; DETMAX on the pre-calibrated parameters): "
            f"{len(pr.data.measurements)} measurements, O1 {o_r:.4f} (random) -> {o_p:.4f} "
            f"(planned); validation RMSE {r_r:.4f} -> {r_p:.4f} mm "
            f"({100.0 * (r_p / r_r - 1.0):+.1f} %); planning took "
            f"{pr.plan.seconds['total']:.1f} s.",
        ]
    return "\n".join(lines)


def measurement_lines(info: dict[str, Any]) -> list[str]:
    """The report's lines on how the sphere centres were measured."""
    if not info:
        return []
    cal, val = info["calibration"], info["validation"]
    how = (
        "rendered sweeps measured by the vision pipeline"
        if info["path"] == "rendered"
        else "geometric (the true centre where the robot stands plus Gaussian noise)"
    )
    lines = [
        f"Measurements: {how}; centre error vs truth (the robot's repeatability and the "
        f"sensor's) RMS {cal['centre_error_rms_um']:.1f} um "
        f"(calibration), {val['centre_error_rms_um']:.1f} um (validation); rejected views "
        f"{cal['rejected']} (calibration), {val['rejected']} (validation)."
    ]
    r = info.get("rendered")
    if r:
        lines.append(
            f"Rendering: {r['sweeps']} sweeps of {r['frames_per_sweep']} frames, per sweep "
            f"{r['render_ms_per_sweep']:.0f} ms render + {r['measure_ms_per_sweep']:.0f} ms "
            f"measure, {r['wall_s']:.1f} s wall on {r['workers']} worker(s)."
        )
    return lines


def markdown_report(demo: DemoResult, model: SystemModel, meta: dict[str, Any]) -> str:
    commit = f", commit {meta['git_commit']}" if meta["git_commit"] else ""
    return (
        "\n\n".join(
            [
                "# rvis demo — simulated cell",
                f"rvis {meta['rvis_version']}{commit}; seed {meta['seed']}; "
                f"{meta['utc_time']}; `{meta['command_line']}`",
                f"Quality gates of the identification: {demo.gates(demo.result).reason}.",
                summary_text(demo).split("\n", 1)[0],
                markdown_table(STATS_HEADER, stats_rows(demo.stats)),
                summary_text(demo).split("\n\n", 1)[1],
                "## Identified parameters (angles in degrees)",
                markdown_table(PARAM_HEADER, parameter_rows(model, demo.result)),
                "![validation errors](validation_errors.png)",
            ]
        )
        + "\n"
    )


__all__ = ["DemoResult", "run_demo", "summary_text"]
