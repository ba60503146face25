"""Parameters JSON (DESIGN.md section 5): the model, nominal and identified values of every
parameter with names, units and standard uncertainties, residual statistics, rank, condition,
and `calibration_temp_c`: the mean cell temperature of the measurements it was identified from
[degC] (null or absent when unknown: files written before it, measurements without a
temperature), at which a rigid version's lengths are the arm's (`carried_from_json`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.files import read_json
from calib.compliance import CompliantModel, CompliantSettings, carry, select_model
from calib.gates import GateReport
from calib.identify import IdentificationResult, with_held
from calib.model import ALL_NAMES, INDEX, PAPER_30, SystemModel, group_of, unit_of
from calib.robot import JointLimits

F64 = NDArray[np.float64]
FORMAT = "rvis-parameters"
FORMAT_VERSION = 1


def model_json(model: SystemModel) -> dict[str, Any]:
    """The model part of a parameters document (name, version, nominal frames, limits)."""
    return {
        "name": model.name,
        "version": model.version,
        "T_part_base_nominal": model.T_part_base_nominal.tolist(),
        "T_flange_sensor_nominal": model.T_flange_sensor_nominal.tolist(),
        "joint_lower_deg": model.limits.lower_deg.tolist(),
        "joint_upper_deg": model.limits.upper_deg.tolist(),
        **_kind_fields(model),
    }


def parameters_json(
    model: SystemModel, x: F64, std: dict[str, float] | None = None
) -> list[dict[str, Any]]:
    """Every parameter: name, group, unit, nominal and value, and for identified ones (those
    in `std`) the standard uncertainty."""
    nominal, std = model.nominal_x(), std or {}
    return [
        {
            "name": name,
            "group": group_of(name),
            "unit": unit_of(name),
            "identified": name in std,
            "nominal": float(nominal[k]),
            "value": float(x[k]),
            "std": float(std.get(name, 0.0)),
        }
        for k, name in enumerate(model.names)
    ]


def plain_document(model: SystemModel, x: F64, source: str) -> dict[str, Any]:
    """A parameters document for values that come from no identification here (the nominal
    model, a commissioning file imported at first start); readable by `from_json`; its
    calibration temperature unknown."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": model_json(model),
        "parameters": parameters_json(model, x),
        "calibration_temp_c": None,
        "success": True,
        "message": source,
        "provenance": {"source": source},
    }


def to_json(
    model: SystemModel,
    result: IdentificationResult,
    gates: GateReport | None = None,
    provenance: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The parameters document. `success` is true only when the optimiser converged and the
    quality gates passed (`gates`; without them only convergence is known)."""
    std = {n: float(v) for n, v in zip(result.active, result.std, strict=True)}
    obs = result.observability
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "model": model_json(model),
        "parameters": parameters_json(model, result.x, std),
        "calibration_temp_c": result.temp_c,
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
        "active": list(result.active),  # the order of the correlation matrix
        "correlation": result.corr.round(6).tolist(),
        "success": bool(result.success and (gates is None or gates.passed)),
        "converged": result.success,
        "gates": None if gates is None else gates.to_json(),
        "status": result.status,
        "message": result.message if gates is None else gates.reason,
        "provenance": provenance,
    }


def _need(data: dict[str, Any], key: str, path: Path, where: str = "") -> Any:
    if key not in data:
        raise InputError("missing field", file=path, field=f"{where}{key}")
    return data[key]


def _finite(value: Any, path: Path, field: str) -> float:
    if not isinstance(value, int | float) or isinstance(value, bool) or not np.isfinite(value):
        raise InputError(f"{value!r} is not a finite number", file=path, field=field)
    return float(value)


def _model(data: dict[str, Any], path: Path) -> SystemModel:
    m = _need(data, "model", path)
    if not isinstance(m, dict):
        raise InputError("expected an object", file=path, field="model")
    known = {(cls.name, cls.version) for cls in (SystemModel, CompliantModel)}
    if (m.get("name"), m.get("version")) not in known:
        names = " or ".join(sorted(f"{n!r} version {v}" for n, v in known))
        raise InputError(
            f"parameters of model {m.get('name')!r} version {m.get('version')!r}; rvis reads "
            f"{names}",
            file=path,
            field="model.name",
        )
    try:
        arrays = [
            np.array(_need(m, k, path, "model."), dtype=float)
            for k in ("T_part_base_nominal", "T_flange_sensor_nominal")
        ]
        limits = [
            np.array(_need(m, k, path, "model."), dtype=float)
            for k in ("joint_lower_deg", "joint_upper_deg")
        ]
        if any(not np.all(np.isfinite(a)) for a in (*arrays, *limits)):
            raise ValueError("non-finite values")
        model = SystemModel(arrays[0].reshape(4, 4), arrays[1].reshape(4, 4), JointLimits(*limits))
    except (ValueError, TypeError) as exc:
        raise InputError(f"bad model: {exc}", file=path, field="model") from exc
    return _with_kind(model, m, path)


class ParamsFile(NamedTuple):
    """A parameters file's model, full parameter vector and calibration temperature [degC]
    (None when the file does not say)."""

    model: SystemModel
    x: F64
    calibration_temp_c: float | None


def from_json(path: str | Path, *, allow_failed: bool = False) -> tuple[SystemModel, F64]:
    """(model, full parameter vector) from a parameters JSON file (`read_params`)."""
    model, x, _ = read_params(path, allow_failed=allow_failed)
    return model, x


def carried_from_json(target: SystemModel, path: str | Path) -> tuple[SystemModel, F64]:
    """(model, x) of a parameters file as a service that identifies `target` uses them
    (calib.compliance.carry): a rigid version carried into a compliant target predicts its
    points at its calibration temperature (the target's reference temperature when the file
    does not say)."""
    model, x, temp_c = read_params(path)
    return carry(target, model, x, temp_c)


def read_params(path: str | Path, *, allow_failed: bool = False) -> ParamsFile:
    """A parameters JSON file, validated: format and version, the model, every parameter of
    the paper's 30 exactly once with a finite value and uncertainty, a finite calibration
    temperature or none, and `success` true (a failed identification is refused unless
    `allow_failed`)."""
    path = Path(path)
    data = read_json(path)
    if data.get("format") != FORMAT:
        raise InputError(
            f"not an rvis parameters file (format {data.get('format')!r})",
            file=path,
            field="format",
        )
    if data.get("format_version") != FORMAT_VERSION:
        raise InputError(
            f"format_version {data.get('format_version')!r} is not {FORMAT_VERSION}",
            file=path,
            field="format_version",
        )
    if data.get("success") is not True and not allow_failed:
        raise InputError(
            f"a failed identification ({data.get('message', 'success is not true')}); "
            "use --allow-failed to read it anyway",
            file=path,
            field="success",
        )
    model = _model(data, path)
    x = model.nominal_x()
    params = _need(data, "parameters", path)
    if not isinstance(params, list):
        raise InputError("expected a list", file=path, field="parameters")
    seen: set[str] = set()
    for k, p in enumerate(params):
        name = p.get("name") if isinstance(p, dict) else None
        if name not in model.names:
            raise InputError(f"unknown parameter {name!r}", file=path, field=f"parameters[{k}]")
        if name in seen:
            raise InputError(f"parameter {name!r} twice", file=path, field=f"parameters[{k}]")
        seen.add(name)
        x[INDEX[name]] = _finite(p.get("value"), path, f"parameters[{k}].value")
        _finite(p.get("std", 0.0), path, f"parameters[{k}].std")
    missing = [n for n in PAPER_30 if n not in seen]
    if missing:
        raise InputError(f"missing parameters: {', '.join(missing)}", file=path, field="parameters")
    temp_c = data.get("calibration_temp_c")
    if temp_c is not None:
        temp_c = _finite(temp_c, path, "calibration_temp_c")
    return ParamsFile(model, x, temp_c)


def _kind_fields(model: SystemModel) -> dict[str, Any]:
    """model.kind and, for the compliant model, its settings (a file without them: rigid)."""
    if not isinstance(model, CompliantModel):
        return {"kind": model.kind}
    return {"kind": model.kind, "compliant": asdict(model.settings)}


#: The kind each model name is of: name and kind must agree (a file without a kind is rigid).
KIND_OF_NAME = {SystemModel.name: SystemModel.kind, CompliantModel.name: CompliantModel.kind}


def _with_kind(model: SystemModel, m: dict[str, Any], path: Path) -> SystemModel:
    """The model of the document's kind, which must be the kind of its name; the compliant
    model's settings are required (every one of them), the rigid model has none."""
    kind, name = m.get("kind", "rigid"), m["name"]
    if kind != KIND_OF_NAME[name]:
        raise InputError(
            f"{kind!r} does not match model.name {name!r} (a {KIND_OF_NAME[name]!r} model)",
            file=path,
            field="model.kind",
        )
    if kind == "rigid":
        if "compliant" in m:
            raise InputError(
                "settings of the compliant model in a rigid one", file=path, field="model.compliant"
            )
        return select_model("rigid", model)
    return select_model("compliant", model, _compliant_settings(m, path))


def _compliant_settings(m: dict[str, Any], path: Path) -> CompliantSettings:
    """model.compliant: every CompliantSettings field, a finite number (identify_expansion: a
    boolean), within the model's ranges."""
    doc = m.get("compliant")
    if not isinstance(doc, dict):
        raise InputError(
            'model.kind "compliant" needs the compliant model\'s settings (an object)',
            file=path,
            field="model.compliant",
        )
    values: dict[str, Any] = {}
    for f in fields(CompliantSettings):
        key = f"model.compliant.{f.name}"
        if f.name not in doc:
            raise InputError("missing field", file=path, field=key)
        v = doc[f.name]
        if f.name == "identify_expansion":
            if not isinstance(v, bool):
                raise InputError(f"{v!r} is not true or false", file=path, field=key)
            values[f.name] = v
        else:
            values[f.name] = _finite(v, path, key)
    unknown = sorted(set(doc) - set(values))
    if unknown:
        raise InputError(f"unknown setting {unknown[0]!r}", file=path, field="model.compliant")
    try:
        return CompliantSettings(**values)
    except ValueError as exc:
        raise InputError(str(exc), file=path, field="model.compliant") from exc


__all__ = ["ALL_NAMES", "carried_from_json", "from_json", "read_params", "to_json"]


def covariance_of(path: str | Path) -> tuple[list[str], F64] | None:
    """(active parameter names, their covariance) of a parameters file, from its standard
    uncertainties and correlation matrix (None when it has none: a nominal or carried
    document); InputError naming the file and field when they do not agree."""
    path = Path(path)
    return document_covariance(read_json(path), path)


def document_covariance(data: dict[str, Any], path: str | Path) -> tuple[list[str], F64] | None:
    """`covariance_of` of a parameters document read already (`path` names it in errors)."""
    path = Path(path)
    active, corr = data.get("active"), data.get("correlation")
    if not active or corr is None:
        return None
    std_of = {str(p.get("name")): p.get("std") for p in data.get("parameters") or []}
    try:
        std = np.array([float(std_of[str(n)]) for n in active])
        c = np.asarray(corr, dtype=float)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"std of an active parameter: {exc}", file=path, field="active") from exc
    if c.shape != (len(active), len(active)) or not np.all(np.isfinite(c)):
        raise InputError(
            f"correlation: expected a finite {len(active)} x {len(active)} matrix, got {c.shape}",
            file=path,
            field="correlation",
        )
    return [str(n) for n in active], c * np.outer(std, std)


def with_held_covariance(
    doc: dict[str, Any],
    before: dict[str, Any],
    path: str | Path,
    gain: Callable[[list[str]], F64],
) -> None:
    """A document identified on a group with the rest held at `before` (a maintenance
    procedure's): its covariance widened to every parameter `before` has one for, the held
    ones' block taken from `before`, the group's its fit's own plus what the held values'
    uncertainty carries into it (calib.identify.with_held: the group's estimate follows the
    held values, by `gain(held)`, d(group)/d(held) in `doc`'s active order: calib.identify.
    held_sensitivity), and the covariance between them. In place; nothing when either has no
    covariance."""
    new, old = document_covariance(doc, path), document_covariance(before, path)
    if new is None or old is None:
        return
    names_n, cov_n = new
    names_o, cov_o = old
    held = [n for n in names_o if n not in names_n]
    io = [names_o.index(n) for n in held]
    cov = with_held(cov_o[np.ix_(io, io)], cov_n, gain(held))
    set_covariance(doc, held + names_n, cov)


def set_covariance(doc: dict[str, Any], names: list[str], cov: F64) -> None:
    """A document's covariance of `names` (its `active` order, correlation matrix and the
    parameters' standard uncertainties), in place."""
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    scale = np.where(std > 0, std, 1.0)
    doc["active"] = names
    doc["correlation"] = (cov / np.outer(scale, scale)).round(6).tolist()
    std_of = dict(zip(names, std.tolist(), strict=True))
    for p in doc.get("parameters") or []:
        if str(p.get("name")) in std_of:
            p["std"] = float(std_of[str(p["name"])])
            p["identified"] = True
