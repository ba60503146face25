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
from app.files import write_json, write_measurements, write_targets
from app.params import to_json
from app.report import (
    PARAM_HEADER,
    STATS_HEADER,
    markdown_table,
    parameter_rows,
    plot_errors,
    stats_rows,
    text_table,
)
from app.simulation import (
    DataSet,
    GeometricMeasurement,
    Measurement,
    collect,
    make_cell,
    measurement_report,
    validation_set,
)
from calib.identify import IdentificationResult, Measurements, identify, residuals
from calib.model import SystemModel
from calib.validation import ErrorStats

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class DemoResult:
    stats: dict[str, ErrorStats]
    breakdown_mm: dict[str, float]
    result: IdentificationResult
    run_dir: Path
    seconds: float
    measurement: dict[str, Any] = field(default_factory=dict)


def _truth_set(ds: DataSet, c_sensor_mm: F64, with_noise: bool) -> Measurements:
    """The data set with true sensor centres (plus the original noise if with_noise)."""
    m = ds.measurements
    c = c_sensor_mm + (m.c_sensor_mm - ds.truth_c_sensor_mm if with_noise else 0.0)
    p = ds.truth_p_part_mm + (m.p_part_mm - ds.truth_p_part_mm if with_noise else 0.0)
    return Measurements(m.q_deg, c, p, m.targets)


def _rmse(e: F64) -> float:
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def error_breakdown(
    cfg: CellConfig, seed: int, model: SystemModel, cal: DataSet, val: DataSet, x_id: F64
) -> dict[str, float]:
    """RMSE [mm] of: the identified parameters alone; compliance alone; noise alone."""
    val_truth = _truth_set(val, val.truth_c_sensor_mm, with_noise=False)
    out = {"parameters_alone": _rmse(residuals(model, x_id, val_truth))}
    clean = identify(model, _truth_set(cal, cal.truth_c_sensor_mm, with_noise=False))
    out["compliance_alone"] = _rmse(residuals(model, clean.x, val_truth))
    rigid = make_cell(cfg, seed=seed, compliance=False)
    m = cal.measurements
    c_rigid = np.array(
        [rigid.centre_in_sensor(q, p)[0] for q, p in zip(m.q_deg, cal.truth_p_part_mm, strict=True)]
    )
    noisy = identify(model, _truth_set(cal, c_rigid, with_noise=True))
    v = val.measurements
    c_val_rigid = np.array(
        [rigid.centre_in_sensor(q, p)[0] for q, p in zip(v.q_deg, val.truth_p_part_mm, strict=True)]
    )
    val_rigid = Measurements(v.q_deg, c_val_rigid, val.truth_p_part_mm, v.targets)
    out["noise_alone"] = _rmse(residuals(model, noisy.x, val_rigid))
    out["validation_measurement_noise"] = _rmse(
        residuals(model, x_id, val.measurements) - residuals(model, x_id, val_truth)
    )
    return out


def run_demo(cfg: CellConfig, seed: int, run_dir: Path, n_validation: int = 100,
             measurement: Measurement | None = None) -> DemoResult:
    """measurement: how sphere centres are measured (default: geometric; `rvis demo` renders)."""
    t0 = time.perf_counter()
    cell = make_cell(cfg, seed=seed)
    model = cfg.model()
    x0 = model.nominal_x()
    rng = np.random.default_rng([seed, 2])
    n_each = int(cfg.calibration["configs_per_sphere"])
    cal = collect(cell, model, x0, cfg.spheres_part_mm, n_each, rng, measurement=measurement)
    val = validation_set(cell, cfg, model, x0, n_validation, rng, measurement)
    result = identify(model, cal.measurements, loss=str(cfg.calibration["loss"]))
    e_before = residuals(model, x0, val.measurements)
    e_after = residuals(model, result.x, val.measurements)
    stats = {"nominal": ErrorStats.of(e_before), "identified": ErrorStats.of(e_after)}
    breakdown = error_breakdown(cfg, seed, model, cal, val, result.x)
    info = measurement_report(measurement or GeometricMeasurement(),
                              {"calibration": cal, "validation": val})
    demo = DemoResult(stats, breakdown, result, run_dir, time.perf_counter() - t0, info)
    _write_run(demo, model, cal, val, {"nominal": e_before, "identified": e_after})
    return demo


def _write_run(
    demo: DemoResult, model: SystemModel, cal: DataSet, val: DataSet, errors: dict[str, F64]
) -> None:
    d = demo.run_dir
    d.mkdir(parents=True, exist_ok=True)
    for name, ds in (("calibration", cal), ("validation", val)):
        m = ds.measurements
        write_measurements(d / f"{name}_measurements.csv", m.targets, m.q_deg, m.c_sensor_mm)
        write_targets(d / f"{name}_targets.csv", ds.targets)
    write_json(d / "params.json", to_json(model, demo.result))
    report: dict[str, Any] = {
        "validation": {k: asdict(v) for k, v in demo.stats.items()},
        "improvement_factor": demo.stats["nominal"].rmse_mm / demo.stats["identified"].rmse_mm,
        "remaining_error_breakdown_rmse_mm": demo.breakdown_mm,
        "observability": demo.result.observability.indices,
        "rank": demo.result.observability.rank,
        "condition": demo.result.observability.condition,
        "seconds": demo.seconds,
        "measurement": demo.measurement,
    }
    write_json(d / "report.json", report)
    plot_errors(d / "validation_errors.png", errors, "Validation errors at 100 positions")
    (d / "report.md").write_text(markdown_report(demo, model), encoding="utf-8")


def summary_text(demo: DemoResult) -> str:
    s = demo.stats
    b = demo.breakdown_mm
    obs = demo.result.observability
    lines = [
        f"Validation at {s['identified'].n} positions (mm):",
        text_table(STATS_HEADER, stats_rows(s)),
        "",
        f"RMSE improved {s['nominal'].rmse_mm / s['identified'].rmse_mm:.1f}x.",
        "What remains (RMSE, mm): identified parameters alone "
        f"{b['parameters_alone']:.4f}; of it, unmodelled compliance alone "
        f"{b['compliance_alone']:.4f}"
        f" and measurement noise alone {b['noise_alone']:.4f}; the validation measurements' own "
        f"noise adds {b['validation_measurement_noise']:.4f}.",
        f"Identification: {len(demo.result.residuals_mm)} measurements, rank {obs.rank}, "
        f"condition {obs.condition:.1f}, "
        + ", ".join(f"{k} {v:.4g}" for k, v in obs.indices.items()),
        *measurement_lines(demo.measurement),
    ]
    return "\n".join(lines)


def measurement_lines(info: dict[str, Any]) -> list[str]:
    """The report's lines on how the sphere centres were measured."""
    if not info:
        return []
    cal, val = info["calibration"], info["validation"]
    how = ("rendered sweeps measured by the vision pipeline" if info["path"] == "rendered"
           else "geometric (true centre plus Gaussian noise)")
    lines = [
        f"Measurements: {how}; centre error vs truth RMS {cal['centre_error_rms_um']:.1f} um "
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


def markdown_report(demo: DemoResult, model: SystemModel) -> str:
    return (
        "\n\n".join(
            [
                "# rvis demo — simulated cell",
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
