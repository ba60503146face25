"""The machine's rvis variables (docs/opcua.md): each one's browse name, where the status reply
(`rvis status --json`) holds its value, its type, unit and range, and how a status value becomes
its OPC UA value (`data_value`: a value the service does not have reads as BadNoValue, a value
the reply left out keeps its last one as UncertainLastUsableValue). app.line.opcua.space builds
them into the address space."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from asyncua import ua

UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
#: engineering units: (UNECE common code, display name, description)
UNITS = {"mm": ("MMT", "mm", "millimetre"), "degC": ("CEL", "°C", "degree Celsius")}
NO_VALUE = ua.StatusCodes.BadNoValue
LEFT_OUT = ua.StatusCodes.UncertainLastUsableValue


def eu_information(unit: str) -> ua.EUInformation:
    """The EngineeringUnits of a UNITS key (UNECE code as the UnitId, OPC UA Part 8)."""
    code, shown, text = UNITS[unit]
    unit_id = int.from_bytes(code.encode("ascii"), "big")
    return ua.EUInformation(UNECE, unit_id, ua.LocalizedText(shown), ua.LocalizedText(text))


def _alarm_count(alarms: Any) -> int:
    return len(alarms)


def _utc(text: Any) -> datetime:
    return datetime.fromisoformat(str(text))


def _open_suspect(rows: Any) -> dict[str, Any] | None:
    """The newest open suspect interval of the status reply, or None."""
    open_ = [r for r in rows or () if r.get("state") == "open"]
    return open_[-1] if open_ else None


def _open_field(rows: Any, key: str) -> Any:
    """A field of the newest open suspect interval (None: none open)."""
    row = _open_suspect(rows)
    return None if row is None else row.get(key)


def _id_or_zero(value: Any) -> int:
    return 0 if value is None else int(value)


@dataclass(frozen=True)
class Var:
    """One variable: browse name, where `rvis status --json` holds its value, its type, unit
    and range (EURange) and how the status value becomes the OPC UA value."""

    name: str
    path: tuple[str, ...]
    vtype: ua.VariantType
    description: str
    unit: str | None = None
    eu_range: tuple[float, float] | None = None
    convert: Callable[[Any], Any] | None = None
    none_is_value: bool = False  # None goes through convert (e.g. PendingCalibration 0)
    none_if: Callable[[Any], bool] | None = None  # values that read as "no value" (BadNoValue)


VARIABLES = (
    Var("ServiceState", ("state",), ua.VariantType.String, "the state word of `rvis status`"),
    Var("Step", ("step",), ua.VariantType.String, "what the service is doing, in a few words"),
    Var(
        "CalibrationVersion",
        ("calibration", "version"),
        ua.VariantType.UInt32,
        "the parameters version in force",
    ),
    Var(
        "CalibrationRmsMm",
        ("calibration", "rms_mm"),
        ua.VariantType.Double,
        "RMS residual of the identification in force (BadNoValue: not identified in-line)",
        unit="mm",
        eu_range=(0.0, 1.0),
    ),
    Var(
        "CalibrationAppliedUtc",
        ("calibration", "applied_utc"),
        ua.VariantType.DateTime,
        "when the parameters in force were applied",
        convert=_utc,
    ),
    Var(
        "PendingCalibration",
        ("pending_calibration",),
        ua.VariantType.UInt32,
        "the calibration waiting for approval (0: none)",
        convert=_id_or_zero,
        none_is_value=True,
    ),
    Var("Windows", ("counters", "windows"), ua.VariantType.UInt32, "clamp windows used"),
    Var("Overruns", ("counters", "overruns"), ua.VariantType.UInt32, "windows overrun"),
    Var("MeasurementsOk", ("measurements", "ok"), ua.VariantType.UInt32, "measurements stored"),
    Var(
        "MeasurementsRejected",
        ("measurements", "rejected"),
        ua.VariantType.UInt32,
        "measurements rejected by the vision checks",
    ),
    Var(
        "CellTemperatureC",
        ("cell_temp_c",),
        ua.VariantType.Double,
        "the cell's air temperature from the PLC (BadNoValue: no sensor)",
        unit="degC",
        eu_range=(-40.0, 80.0),
    ),
    Var(
        "AccuracyU95Mm",
        ("accuracy", "u95_mm"),
        ua.VariantType.Double,
        "the expanded uncertainty U95 (k for 95 %) of a point measured now, from the in-line"
        " check standard (BadNoValue: no evidence yet; app/line/accuracy.py)",
        unit="mm",
        eu_range=(0.0, 100.0),
    ),
    Var(
        "AccuracyLimitMm",
        ("accuracy", "limit_mm"),
        ua.VariantType.Double,
        "the plant's limit for U95 ([service] accuracy_limit_mm)",
        unit="mm",
        eu_range=(0.0, 100.0),
    ),
    Var(
        "AccuracyVouched",
        ("accuracy", "vouched"),
        ua.VariantType.Boolean,
        "the cell vouches for U95 within the limit (false: the bodies measured now are in a"
        " suspect interval)",
    ),
    Var(
        "ActiveAlarms",
        ("alarms",),
        ua.VariantType.UInt32,
        "alarms raised, acknowledged or shelved (each also an AlarmConditionType event)",
        convert=_alarm_count,
    ),
    Var(
        "SuspectOpen",
        ("suspect_intervals",),
        ua.VariantType.Boolean,
        "a suspect interval is open: the calibration in force may be wrong since SuspectStartUtc"
        " (bodies measured meanwhile may need measuring again; rvis state suspects)",
        convert=lambda rows: _open_suspect(rows) is not None,
    ),
    Var(
        "SuspectStartUtc",
        ("suspect_intervals",),
        ua.VariantType.DateTime,
        "the start of the open suspect interval (BadNoValue: none open)",
        convert=lambda rows: _utc(_open_field(rows, "start_utc")),
        none_if=lambda rows: _open_field(rows, "start_utc") is None,
    ),
    Var(
        "SuspectSizeMm",
        ("suspect_intervals",),
        ua.VariantType.Double,
        "the open suspect interval's estimated error at the standoff (BadNoValue: none open)",
        unit="mm",
        eu_range=(0.0, 10.0),
        convert=lambda rows: _open_field(rows, "size_mm"),
        none_if=lambda rows: _open_field(rows, "size_mm") is None,
    ),
    Var(
        "SuspectBodies",
        ("suspect_intervals",),
        ua.VariantType.String,
        "the bodies measured so far in the open suspect interval, as a JSON array of the ids the"
        " line PLC gave them ([line] plc_body_id; [] when it gives none; BadNoValue: none open)",
        convert=lambda rows: json.dumps(_open_field(rows, "bodies") or []),
        none_if=lambda rows: _open_suspect(rows) is None,
    ),
    Var(
        "SuspectIntervals",
        ("suspect_intervals",),
        ua.VariantType.String,
        "the last suspect intervals as JSON (start_utc, end_utc, size_mm, group, text, bodies),"
        " oldest first, as `rvis state suspects --json` prints them",
        convert=lambda rows: json.dumps(rows),
    ),
)


def sphere_vars(sphere: str) -> tuple[Var, ...]:
    """One sphere's measurements in the one estimator's window (app.line.estimate)."""
    return (
        Var(
            "ResidualMm",
            ("spheres", sphere, "residual_mm"),
            ua.VariantType.Double,
            "the newest measurement's distance from where the parameters in force put the"
            " sphere's centre",
            unit="mm",
            eu_range=(0.0, 1.0),
        ),
        Var(
            "PosteriorRmsMm",
            ("spheres", sphere, "posterior_rms_mm"),
            ua.VariantType.Double,
            "RMS residual of the sphere's measurements in the estimator's window once its"
            " estimate of the cell's drift is taken off",
            unit="mm",
            eu_range=(0.0, 1.0),
        ),
    )


_MISSING = object()


def lookup(status: Mapping[str, Any], path: tuple[str, ...]) -> Any:
    """The value at `path` of a status reply (_MISSING when the reply left it out)."""
    value: Any = status
    for key in path:
        if not isinstance(value, Mapping) or key not in value:
            return _MISSING
        value = value[key]
    return value


def data_value(var: Var, raw: Any, t: datetime, last: ua.Variant | None) -> ua.DataValue:
    """The OPC UA value of `var` for the status value `raw`, timestamped `t`."""
    if raw is _MISSING and last is not None and last.VariantType != ua.VariantType.Null:
        return ua.DataValue(last, StatusCode=ua.StatusCode(LEFT_OUT), SourceTimestamp=t)
    no_value = raw is None and not var.none_is_value
    if raw is _MISSING or no_value or (var.none_if is not None and var.none_if(raw)):
        return ua.DataValue(StatusCode=ua.StatusCode(NO_VALUE), SourceTimestamp=t)
    value = var.convert(raw) if var.convert is not None else raw
    if var.vtype == ua.VariantType.Double:
        value = float(value)
    return ua.DataValue(ua.Variant(value, var.vtype), SourceTimestamp=t)
