"""Parameters JSON (DESIGN.md section 5): the model, nominal and identified values of every
parameter with names, units and standard uncertainties, residual statistics, rank, condition."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.files import read_json
from calib.compliance import CompliantModel, CompliantSettings, select_model
from calib.identify import IdentificationResult
from calib.model import ALL_NAMES, INDEX, SystemModel, group_of, unit_of
from calib.robot import JointLimits

F64 = NDArray[np.float64]
FORMAT = "rvis-parameters"
FORMAT_VERSION = 1


def to_json(model: SystemModel, result: IdentificationResult) -> dict[str, Any]:
    nominal = model.nominal_x()
    std = dict(zip(result.active, result.std, strict=True))
    params = [
        {
            "name": name,
            "group": group_of(name),
            "unit": unit_of(name),
            "identified": name in std,
            "nominal": float(nominal[k]),
            "value": float(result.x[k]),
            "std": float(std[name]) if name in std else 0.0,
        }
        for k, name in enumerate(model.names)
    ]
    obs = result.observability
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": {
            "name": model.name,
            "version": model.version,
            "T_part_base_nominal": model.T_part_base_nominal.tolist(),
            "T_flange_sensor_nominal": model.T_flange_sensor_nominal.tolist(),
            "joint_lower_deg": model.limits.lower_deg.tolist(),
            "joint_upper_deg": model.limits.upper_deg.tolist(),
            **_kind_fields(model),
        },
        "parameters": params,
        "residuals": {
            "n_measurements": int(result.residuals_mm.shape[0]),
            "rms_mm": result.rms_mm,
            "max_mm": result.max_mm,
            "sigma_mm": result.sigma_mm,
        },
        "rank": obs.rank,
        "n_parameters": obs.n_params,
        "condition": obs.condition,
        "observability": obs.indices,
        "correlation": result.corr.round(6).tolist(),
        "success": result.success,
        "status": result.status,
        "message": result.message,
    }


def from_json(path: str | Path) -> tuple[SystemModel, F64]:
    """(model, full parameter vector) from a parameters JSON file."""
    data = read_json(path)

    def need(obj: dict[str, Any], key: str, where: str) -> Any:
        if key not in obj:
            raise InputError("missing field", file=path, field=f"{where}{key}")
        return obj[key]

    if data.get("format") != FORMAT:
        raise InputError(
            f"not an rvis parameters file (format {data.get('format')!r})",
            file=path,
            field="format",
        )
    m = need(data, "model", "")
    try:
        model = SystemModel(
            np.array(need(m, "T_part_base_nominal", "model."), dtype=float).reshape(4, 4),
            np.array(need(m, "T_flange_sensor_nominal", "model."), dtype=float).reshape(4, 4),
            JointLimits(
                np.array(need(m, "joint_lower_deg", "model."), dtype=float),
                np.array(need(m, "joint_upper_deg", "model."), dtype=float),
            ),
        )
        model = _with_kind(model, m)
    except (ValueError, TypeError) as exc:
        raise InputError(f"bad model: {exc}", file=path, field="model") from exc
    x = model.nominal_x()
    for k, p in enumerate(need(data, "parameters", "")):
        name = p.get("name") if isinstance(p, dict) else None
        if name not in model.names:
            raise InputError(f"unknown parameter {name!r}", file=path, field=f"parameters[{k}]")
        value = p.get("value")
        if not isinstance(value, int | float) or not np.isfinite(value):
            raise InputError(
                "value is not a finite number", file=path, field=f"parameters[{k}].value"
            )
        x[INDEX[name]] = float(value)
    return model, x


def _kind_fields(model: SystemModel) -> dict[str, Any]:
    """model.kind and, for the compliant model, its settings (a file without them: rigid)."""
    if not isinstance(model, CompliantModel):
        return {"kind": model.kind}
    return {"kind": model.kind, "compliant": asdict(model.settings)}


def _with_kind(model: SystemModel, m: dict[str, Any]) -> SystemModel:
    kind = m.get("kind", "rigid")
    settings = m.get("compliant", {}) if kind == "compliant" else {}
    if not isinstance(settings, dict):
        raise ValueError("model.compliant is not an object")
    return select_model(str(kind), model, CompliantSettings(**settings))


__all__ = ["ALL_NAMES", "from_json", "to_json"]
