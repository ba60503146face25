"""Tracker exports imported from CSV: ``tracker+file://targets.csv``.

Header ``target,x_mm,y_mm,z_mm`` (the Targets CSV of DESIGN.md), optionally followed by
``rms_mm,time_utc,temperature_c,pressure_hpa``. Points are in the part frame. A bad file is an
ExportError (a DeviceConfigError) naming the file, line (header = line 1) and field.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from drivers.errors import DeviceConfigError, DeviceFault
from drivers.tracker import Tracker, TrackerMeasurement, TrackerStatus
from drivers.url import DeviceUrl

REQUIRED = ("target", "x_mm", "y_mm", "z_mm")
OPTIONAL_NUMBERS = ("rms_mm", "temperature_c", "pressure_hpa")


class ExportError(DeviceConfigError):
    """A bad tracker export: its message "file:line: field 'f': reason", and each part apart
    (`path`, `line`, `field`: None where the problem has none; `reason`), so that a caller can
    name the file the user gave rather than a copy of it."""

    def __init__(
        self, path: Path, reason: str, line: int | None = None, field: str | None = None
    ) -> None:
        self.path, self.reason, self.line, self.field = path, reason, line, field
        where = str(path) if line is None else f"{path}:{line}"
        super().__init__(
            f"{where}: {reason}" if field is None else f"{where}: field '{field}': {reason}"
        )


def read_targets_csv(path: Path) -> dict[str, TrackerMeasurement]:
    """Parse a tracker export; ExportError (a DeviceConfigError) with file, line and field on
    any problem."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ExportError(path, f"cannot read: {exc}") from exc
    rows = csv.DictReader(text.splitlines())
    missing = [f for f in REQUIRED if f not in (rows.fieldnames or [])]
    if missing:
        raise ExportError(path, "missing from the header", 1, missing[0])
    out: dict[str, TrackerMeasurement] = {}
    for line, row in enumerate(rows, start=2):
        out.update([_row(path, line, row, out)])
    if not out:
        raise ExportError(path, "no targets")
    return out


def _row(
    path: Path, line: int, row: dict[str, Any], seen: dict[str, TrackerMeasurement]
) -> tuple[str, TrackerMeasurement]:
    def number(field: str, default: float | None = None) -> float:
        raw = row.get(field)
        if (raw is None or raw == "") and default is not None:
            return default
        try:
            value = float(raw)  # type: ignore[arg-type]
        except (TypeError, ValueError) as exc:
            raise ExportError(path, f"not a number: {raw!r}", line, field) from exc
        if not math.isfinite(value):
            raise ExportError(path, "not finite", line, field)
        return value

    target = (row.get("target") or "").strip()
    if not target:
        raise ExportError(path, "empty", line, "target")
    if target in seen:
        raise ExportError(path, f"duplicate {target!r}", line, "target")
    point = np.array([number("x_mm"), number("y_mm"), number("z_mm")])
    return target, TrackerMeasurement(
        target,
        point,
        number("rms_mm", 0.0),
        str(row.get("time_utc") or ""),
        number("temperature_c", 20.0),
        number("pressure_hpa", 1013.25),
    )


class FileTracker(Tracker):
    """``FileTracker(Path("targets.csv"))``: the export's points, one per target id."""

    def __init__(self, path: str | Path, **kw: Any) -> None:
        kw.setdefault("name", f"tracker+file://{path}")
        super().__init__(**kw)
        self.path = Path(path)
        self._points: dict[str, TrackerMeasurement] = {}

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FileTracker:
        if not url.location:
            raise DeviceConfigError(f"{url.raw}: no file")
        return cls(url.location, **options)

    def _open(self) -> None:
        self._points = read_targets_csv(self.path)

    def _close(self) -> None:
        self._points = {}

    def describe(self) -> str:
        self._check_open()
        return f"tracker export {self.path} ({len(self._points)} targets)"

    def _targets(self) -> list[str]:
        return list(self._points)

    def _status(self) -> TrackerStatus:
        return TrackerStatus(ready=True, target_in_beam=False, detail="file import")

    def _measure(self, target_id: str, timeout_s: float) -> TrackerMeasurement:
        try:
            return self._points[target_id]
        except KeyError as exc:
            raise DeviceFault(f"{self.path}: no target {target_id!r}", code=10) from exc
