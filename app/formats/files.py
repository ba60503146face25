"""The file contracts of DESIGN.md section 5: measurements, targets and errors CSV, parameters
JSON. Every reader validates and reports a bad value as an InputError naming file, line (the
header is line 1) and field."""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import math
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.jsontext import dumps_json as dumps_json
from app.formats.jsontext import finite_json as finite_json
from calib.robot import JointLimits

F64 = NDArray[np.float64]

MEASUREMENT_COLUMNS = (
    "target",
    "j1_deg",
    "j2_deg",
    "j3_deg",
    "j4_deg",
    "j5_deg",
    "j6_deg",
    "sx_mm",
    "sy_mm",
    "sz_mm",
)
TARGET_COLUMNS = ("target", "x_mm", "y_mm", "z_mm")
ERROR_COLUMNS = ("target", "x_mm", "y_mm", "z_mm", "ex_mm", "ey_mm", "ez_mm", "e_mm")
#: Magnitudes beyond these are typing errors, not measurements (a cell is a few metres wide).
MAX_COORD_MM = 1e5
MAX_ANGLE_DEG = 720.0


def csv_rows(path: Path, columns: Sequence[str]) -> Iterator[tuple[int, dict[str, str]]]:
    """(line number, row) of a CSV file whose header must hold `columns`."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"cannot read file: {reason}", file=path) from exc
    reader = csv.reader(text.splitlines())
    header = [h.strip() for h in next(reader, [])]
    if not header:
        raise InputError("empty file: expected a header " + ",".join(columns), file=path, line=1)
    for col in columns:
        if col not in header:
            raise InputError("missing column", file=path, line=1, field=col)
    for line, raw in enumerate(reader, start=2):
        if not raw or all(not cell.strip() for cell in raw):
            continue
        if len(raw) != len(header):
            raise InputError(
                f"{len(raw)} fields where the header has {len(header)}", file=path, line=line
            )
        yield line, {h: cell.strip() for h, cell in zip(header, raw, strict=True)}


def check_joint_limits(
    q_deg: Sequence[float] | NDArray[np.float64], limits: JointLimits, path: Path, line: int
) -> None:
    """InputError naming the joint's column (`j1_deg` ...) when a joint is outside its limits."""
    for j, value in enumerate(q_deg):
        if not limits.lower_deg[j] <= value <= limits.upper_deg[j]:
            raise InputError(
                f"{value:g} deg is outside the joint limits "
                f"[{limits.lower_deg[j]:g}, {limits.upper_deg[j]:g}]",
                file=path,
                line=line,
                field=f"j{j + 1}_deg",
            )


def csv_number(row: dict[str, str], field: str, path: Path, line: int) -> float:
    """The finite number in `field`, within the magnitude its unit allows (_deg, _mm)."""
    text = row[field]
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"'{text}' is not a number", file=path, line=line, field=field) from None
    if not math.isfinite(value):
        raise InputError(f"'{text}' is not a finite number", file=path, line=line, field=field)
    limit = MAX_ANGLE_DEG if field.endswith("_deg") else MAX_COORD_MM
    if abs(value) > limit:
        unit = "deg" if field.endswith("_deg") else "mm"
        raise InputError(
            f"{value:g} {unit} is beyond +-{limit:g} {unit}", file=path, line=line, field=field
        )
    return value


def _target_id(row: dict[str, str], path: Path, line: int) -> str:
    tid = row["target"]
    if not tid:
        raise InputError("empty target id", file=path, line=line, field="target")
    return tid


def read_targets(path: str | Path) -> dict[str, F64]:
    """Targets CSV -> {target id: centre in the part frame (3,) [mm]}."""
    path = Path(path)
    out: dict[str, F64] = {}
    for line, row in csv_rows(path, TARGET_COLUMNS):
        tid = _target_id(row, path, line)
        if tid in out:
            raise InputError(f"duplicate target '{tid}'", file=path, line=line, field="target")
        out[tid] = np.array([csv_number(row, f, path, line) for f in TARGET_COLUMNS[1:]])
    if not out:
        raise InputError("no targets in file", file=path)
    return out


#: Optional measurements column: the cell temperature [degC] at the measurement.
TEMP_COLUMN = "temp_c"
TEMP_RANGE_C = (-40.0, 100.0)


class MeasurementRows:
    """Measurements CSV contents: ids (m,), q_deg (m, 6), c_sensor_mm (m, 3), line numbers,
    the cell temperatures (m,) [degC] when the file has a temp_c column (else None)."""

    def __init__(
        self,
        path: Path,
        targets: list[str],
        q_deg: F64,
        c_sensor_mm: F64,
        lines: list[int],
        temp_c: F64 | None = None,
    ) -> None:
        self.path, self.targets, self.q_deg, self.c_sensor_mm, self.lines = (
            path,
            targets,
            q_deg,
            c_sensor_mm,
            lines,
        )
        self.temp_c = temp_c


def _temperature(row: dict[str, str], path: Path, line: int) -> float:
    t = csv_number(row, TEMP_COLUMN, path, line)
    if not TEMP_RANGE_C[0] <= t <= TEMP_RANGE_C[1]:
        raise InputError(
            f"{t:g} degC is outside [{TEMP_RANGE_C[0]:g}, {TEMP_RANGE_C[1]:g}]",
            file=path,
            line=line,
            field=TEMP_COLUMN,
        )
    return t


def read_measurements(path: str | Path, limits: JointLimits | None = None) -> MeasurementRows:
    """Measurements CSV; joint angles are checked against the limits (controller angles)."""
    path = Path(path)
    limits = limits or JointLimits()
    ids: list[str] = []
    qs: list[list[float]] = []
    cs: list[list[float]] = []
    lines: list[int] = []
    temps: list[float] = []
    seen: dict[tuple[str, ...], int] = {}
    for line, row in csv_rows(path, MEASUREMENT_COLUMNS):
        key = tuple(row[c] for c in MEASUREMENT_COLUMNS)
        if key in seen:
            raise InputError(f"duplicate of line {seen[key]}", file=path, line=line)
        seen[key] = line
        if TEMP_COLUMN in row:
            temps.append(_temperature(row, path, line))
        ids.append(_target_id(row, path, line))
        q = [csv_number(row, f, path, line) for f in MEASUREMENT_COLUMNS[1:7]]
        check_joint_limits(q, limits, path, line)
        qs.append(q)
        cs.append([csv_number(row, f, path, line) for f in MEASUREMENT_COLUMNS[7:]])
        lines.append(line)
    if not ids:
        raise InputError("no measurements in file", file=path)
    temp_c = np.array(temps) if temps else None
    return MeasurementRows(path, ids, np.array(qs), np.array(cs), lines, temp_c)


def match_targets(rows: MeasurementRows, targets: dict[str, F64], targets_path: Path) -> F64:
    """Tracker centres (m, 3) for each measurement row; unknown ids name their line."""
    out = np.zeros((len(rows.targets), 3))
    for k, (tid, line) in enumerate(zip(rows.targets, rows.lines, strict=True)):
        if tid not in targets:
            raise InputError(
                f"unknown target id '{tid}' (not in {targets_path})",
                file=rows.path,
                line=line,
                field="target",
            )
        out[k] = targets[tid]
    return out


def _write_reason(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "no space left on the device"
    if exc.errno in (errno.EEXIST, errno.ENOTDIR):
        return "a parent of this path is a file, not a folder"
    return exc.strerror or str(exc)


def _umask() -> int:
    """The process's umask, read without changing it (Linux; 0o022 elsewhere)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    return 0o022


def replace_atomically(path: str | Path, data: bytes) -> None:
    """Replace `path` by `data` so that a reader (or a restart after a crash) sees the old file
    or the new one, never a part: a temporary file in the same directory, fsync, rename over
    `path`, fsync the directory. OSError on failure, with `path` left as it was."""
    path = Path(path)
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), mode)
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


def write_bytes(path: str | Path, data: bytes) -> None:
    """`replace_atomically`, creating missing parent folders; any problem with the path is an
    InputError naming it (exit code 2)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a directory, expected a file name", file=path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        replace_atomically(path, data)
    except OSError as exc:
        raise InputError(f"cannot write: {_write_reason(exc)}", file=path) from None


def check_output(path: str | Path) -> Path:
    """Fail early (before any work) when `path` cannot become a file: it is a folder, a parent
    is a file, or the nearest existing folder is not writable. Returns the path."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a directory, expected a file name", file=path)
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError("cannot write: a parent of this path is a file, not a folder", file=path)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"cannot write: folder {parent} is not writable", file=path)
    return path


def fsync_dir(directory: str | Path) -> None:
    """Make a rename in `directory` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_text(path: str | Path, text: str) -> None:
    """`write_bytes` of UTF-8 text with LF line ends."""
    write_bytes(path, text.encode("utf-8"))


def write_csv(path: str | Path, columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([f"{v:.6f}" if isinstance(v, float) else v for v in row])
    write_text(path, buf.getvalue())


def write_measurements(
    path: str | Path,
    targets: Sequence[str],
    q_deg: F64,
    c_mm: F64,
    temp_c: F64 | None = None,
) -> None:
    rows = [
        [t, *map(float, q), *map(float, c)] for t, q, c in zip(targets, q_deg, c_mm, strict=True)
    ]
    if temp_c is None:
        write_csv(path, MEASUREMENT_COLUMNS, rows)
        return
    rows = [[*r, float(t)] for r, t in zip(rows, temp_c, strict=True)]
    write_csv(path, (*MEASUREMENT_COLUMNS, TEMP_COLUMN), rows)


def write_targets(path: str | Path, targets: dict[str, F64]) -> None:
    write_csv(path, TARGET_COLUMNS, [[t, *map(float, p)] for t, p in targets.items()])


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def read_json(path: str | Path) -> dict[str, Any]:
    """A JSON object from `path` (UTF-8, BOM accepted; NaN and Infinity refused)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"), parse_constant=_no_constant)
    except OSError as exc:
        raise InputError(f"cannot read file: {exc.strerror or exc}", file=path) from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text ({exc.reason})", file=path) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"invalid JSON: {exc.msg}", file=path, line=exc.lineno) from exc
    except ValueError as exc:
        raise InputError(f"invalid JSON: {exc}", file=path) from exc
    if not isinstance(data, dict):
        raise InputError("expected a JSON object", file=path, line=1)
    return data


def write_json(path: str | Path, data: dict[str, Any]) -> None:
    write_text(path, dumps_json(data, indent=2) + "\n")
