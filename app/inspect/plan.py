"""The feature plan of a part type: the body's features from CAD and their characteristics with
tolerances (`features.toml` beside the cell file; its schema in docs/inspection.md).

    format = "rvis-features/1"
    part = "SIM-BIW-01"                    # part number (AQDEF K1001)
    description = "simulated body side"    # (K1002)
    clamp_sd_mm = 0.012                    # the fixture's clamping repeatability (optional)

    [[feature]]
    id = "H01"
    type = "hole"                          # hole | slot | surface
    position_mm = [1500.0, -300.0, 150.0]  # centre on the sheet's top face, part frame
    normal = [-0.9, 0.0, 0.43]             # out of the sheet, towards the sensor
    diameter_mm = 10.0                     # hole; a slot has width_mm, length_mm, axis
    thickness_mm = 0.8                     # the sheet's (optional, 0.8)
    position_tol_mm = [-0.5, 0.5]          # hole and slot: X, Y, Z each
    size_tol_mm = [-0.2, 0.2]              # hole: D; slot: W and L
    # surface: normal_tol_mm = [-0.7, 0.7] for N, the deviation along the normal

`clamp_sd_mm`: the fixture's clamping repeatability for this part type, one standard deviation
[mm] per axis at the features (a clamping study's, or the fixture's specification): a body's
values are in the fixture's frame, a CMM's in the body's own, so each value's U95 holds it
(app.inspect.values); 0 when not given, and the U95 then leaves the clamping out.

Characteristics (`Characteristic`): a hole's X, Y, Z (its centre along the part frame's axes) and
D; a slot's X, Y, Z, W and L; a surface point's N. Tolerances are deviations from the nominal
[lower, upper], lower < upper.

Every field is checked; a wrong one is an InputError naming the file, the line, the feature and
the field (exit 2): an unknown type, a missing or inverted tolerance, a nominal outside the
robot's reach, a duplicate id, a normal of zero length.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config.tomlfile import read_toml
from app.errors import InputError
from calib.datasheet import REACH_MM

F64 = NDArray[np.float64]
FORMAT = "rvis-features/1"
TYPES = ("hole", "slot", "surface")
#: the characteristics of each type: (name, kind, the tolerance field)
CHARACTERISTICS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "hole": (
        ("X", "position", "position_tol_mm"),
        ("Y", "position", "position_tol_mm"),
        ("Z", "position", "position_tol_mm"),
        ("D", "size", "size_tol_mm"),
    ),
    "slot": (
        ("X", "position", "position_tol_mm"),
        ("Y", "position", "position_tol_mm"),
        ("Z", "position", "position_tol_mm"),
        ("W", "size", "size_tol_mm"),
        ("L", "size", "size_tol_mm"),
    ),
    "surface": (("N", "position", "normal_tol_mm"),),
}
_SIZES = {"hole": ("diameter_mm",), "slot": ("width_mm", "length_mm"), "surface": ()}
_KNOWN = {
    "id",
    "type",
    "position_mm",
    "normal",
    "axis",
    "thickness_mm",
    "diameter_mm",
    "width_mm",
    "length_mm",
    "position_tol_mm",
    "size_tol_mm",
    "normal_tol_mm",
}


@dataclass(frozen=True)
class Characteristic:
    """One characteristic: its feature and name (X, Y, Z, D, W, L, N), kind (position or
    size), nominal [mm], tolerance (lower, upper) as deviations [mm]."""

    feature: str
    name: str
    kind: str
    nominal_mm: float
    tol_mm: tuple[float, float]

    @property
    def key(self) -> str:
        return f"{self.feature}.{self.name}"

    @property
    def limits_mm(self) -> tuple[float, float]:
        """The absolute limits (AQDEF K2110/K2111)."""
        return self.nominal_mm + self.tol_mm[0], self.nominal_mm + self.tol_mm[1]


@dataclass(frozen=True)
class Feature:
    """A feature from CAD (part frame, mm): id, type, position_mm (3,), unit normal (3,),
    unit axis (3,) (a slot's long axis; zeros otherwise), size_mm, thickness_mm, and its
    tolerances by field name."""

    id: str
    type: str
    position_mm: F64
    normal: F64
    axis: F64
    size_mm: tuple[float, ...]
    thickness_mm: float
    tolerances: dict[str, tuple[float, float]]

    def characteristics(self) -> list[Characteristic]:
        out = []
        sizes = iter(self.size_mm)
        for name, kind, tol in CHARACTERISTICS[self.type]:
            if kind == "size":
                nominal = next(sizes)
            elif name == "N":
                nominal = 0.0
            else:
                nominal = float(self.position_mm["XYZ".index(name)])
            out.append(Characteristic(self.id, name, kind, nominal, self.tolerances[tol]))
        return out


@dataclass(frozen=True)
class FeaturePlan:
    """A part type: part number, description, its features in file order, the file, and the
    fixture's clamping repeatability [mm] (module docstring)."""

    part: str
    description: str
    features: tuple[Feature, ...]
    source: str = ""
    clamp_sd_mm: float = 0.0

    def characteristics(self) -> list[Characteristic]:
        return [c for f in self.features for c in f.characteristics()]

    def feature(self, feature_id: str) -> Feature:
        for f in self.features:
            if f.id == feature_id:
                return f
        raise KeyError(feature_id)


def load_features(path: str | Path, T_part_base: F64 | None = None) -> FeaturePlan:
    """The feature plan at `path`, every field checked (module docstring); T_part_base: the
    cell's, to refuse a nominal outside the robot's reach (None: not checked)."""
    doc, text = read_toml(path)
    lines = _feature_lines(text)
    if doc.get("format") != FORMAT:
        raise InputError(
            f"format: expected {FORMAT!r}, got {doc.get('format')!r}", file=path, field="format"
        )
    unknown = sorted(set(doc) - {"format", "part", "description", "clamp_sd_mm", "feature"})
    if unknown:
        raise InputError(f"unknown key {unknown[0]!r}", file=path, field=unknown[0])
    rows = doc.get("feature")
    if not isinstance(rows, list) or not rows:
        raise InputError("no [[feature]] in the file", file=path, field="feature")
    features: list[Feature] = []
    seen: dict[str, int] = {}
    for k, row in enumerate(rows):
        where = _Where(path, lines[k] if k < len(lines) else None, text, row)
        f = _feature(row, where, k)
        if f.id in seen:
            raise where.error("id", f"duplicate id {f.id!r} (feature {seen[f.id] + 1} has it)")
        seen[f.id] = k
        if T_part_base is not None:
            p_base = np.linalg.solve(T_part_base, np.append(f.position_mm, 1.0))[:3]
            if float(np.linalg.norm(p_base)) > REACH_MM:
                raise where.error(
                    "position_mm",
                    f"{np.linalg.norm(p_base):.0f} mm from the robot's base, outside"
                    f" its reach ({REACH_MM:g} mm): outside the workspace",
                )
        features.append(f)
    part = str(doc.get("part", "")).strip()
    if not part:
        raise InputError("part: expected the part number", file=path, field="part")
    clamp = doc.get("clamp_sd_mm", 0.0)
    if isinstance(clamp, bool) or not isinstance(clamp, int | float) or not 0 <= clamp < 10:
        raise InputError(
            f"clamp_sd_mm: expected a number of mm from 0 to 10, got {clamp!r}",
            file=path,
            line=_top_line(text, "clamp_sd_mm"),
            field="clamp_sd_mm",
        )
    description = str(doc.get("description", ""))
    return FeaturePlan(part, description, tuple(features), str(path), float(clamp))


def _top_line(text: str, key: str) -> int | None:
    """The line of a top-level `key = ...` (before the first [[feature]])."""
    for k, line in enumerate(text.splitlines(), start=1):
        if line.strip().startswith("[["):
            return None
        if re.match(rf"\s*{re.escape(key)}\s*=", line):
            return k
    return None


class _Where:
    """Where a feature stands in the file, for its errors."""

    def __init__(self, path: str | Path, line: int | None, text: str, row: Any) -> None:
        self.path, self.line, self.text = path, line, text
        self.id = str(row.get("id", "?")) if isinstance(row, dict) else "?"

    def error(self, field: str, reason: str) -> InputError:
        return InputError(
            f"feature {self.id!r}: {reason}", file=self.path, line=self._line(field), field=field
        )

    def _line(self, field: str) -> int | None:
        if self.line is None:
            return None
        body = self.text.splitlines()[self.line :]
        for n, text in enumerate(body, start=self.line + 1):
            if text.lstrip().startswith("["):
                break
            if re.match(rf"^\s*{re.escape(field)}\s*=", text):
                return n
        return self.line


def _feature_lines(text: str) -> list[int]:
    return [
        n for n, t in enumerate(text.splitlines(), 1) if re.match(r"^\s*\[\[\s*feature\s*\]\]", t)
    ]


def _feature(row: Any, where: _Where, k: int) -> Feature:
    if not isinstance(row, dict):
        raise where.error("feature", "expected a table")
    unknown = sorted(set(row) - _KNOWN)
    if unknown:
        raise where.error(unknown[0], "unknown field")
    fid = row.get("id")
    if not isinstance(fid, str) or not re.fullmatch(r"[A-Za-z0-9_\-]{1,32}", fid):
        raise where.error("id", f"expected an id of 1-32 letters, digits, '_' or '-', got {fid!r}")
    kind = row.get("type")
    if kind not in TYPES:
        raise where.error("type", f"unknown type {kind!r} (expected one of {', '.join(TYPES)})")
    position = _vector(row, "position_mm", where, 1e5)
    normal = _unit(row, "normal", where)
    axis = _unit(row, "axis", where) if kind == "slot" else np.zeros(3)
    if kind == "slot" and abs(float(axis @ normal)) > 0.1:
        raise where.error("axis", "the slot's axis must lie in the sheet (normal to `normal`)")
    sizes = tuple(_number(row, name, where, 0.5, 100.0) for name in _SIZES[kind])
    if kind == "slot" and sizes[1] <= sizes[0]:
        raise where.error("length_mm", f"{sizes[1]:g} mm: a slot is longer than it is wide")
    thickness = _number(row, "thickness_mm", where, 0.1, 10.0, default=0.8)
    tols = {tol: _tolerance(row, tol, where) for _, _, tol in CHARACTERISTICS[kind]}
    return Feature(fid, kind, position, normal, axis, sizes, thickness, tols)


def _number(
    row: dict[str, Any],
    name: str,
    where: _Where,
    lo: float,
    hi: float,
    default: float | None = None,
) -> float:
    v = row.get(name, default)
    if v is None:
        raise where.error(name, "missing")
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise where.error(name, f"expected a number, got {v!r}")
    if not lo <= v <= hi:
        raise where.error(name, f"{v!r} outside {lo:g}..{hi:g}")
    return float(v)


def _vector(row: dict[str, Any], name: str, where: _Where, bound: float) -> F64:
    v = row.get(name)
    if v is None:
        raise where.error(name, "missing")
    ok = isinstance(v, list) and len(v) == 3
    ok = ok and all(not isinstance(a, bool) and isinstance(a, int | float) for a in v)
    if not ok or not all(math.isfinite(a) and abs(a) <= bound for a in v):
        raise where.error(name, f"expected three finite numbers within +-{bound:g}, got {v!r}")
    return np.array(v, dtype=float)


def _unit(row: dict[str, Any], name: str, where: _Where) -> F64:
    v = _vector(row, name, where, 1e5)
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise where.error(name, "a direction of zero length")
    return v / n


def _tolerance(row: dict[str, Any], name: str, where: _Where) -> tuple[float, float]:
    v = row.get(name)
    if v is None:
        raise where.error(name, "missing: the tolerance [lower, upper] as deviations in mm")
    ok = isinstance(v, list) and len(v) == 2
    ok = ok and all(not isinstance(a, bool) and isinstance(a, int | float) for a in v)
    if not ok or not all(math.isfinite(a) and abs(a) <= 100 for a in v):
        raise where.error(name, f"expected [lower, upper] in mm, got {v!r}")
    if not v[0] < v[1]:
        raise where.error(name, f"inverted or empty: lower {v[0]!r} must be below upper {v[1]!r}")
    return float(v[0]), float(v[1])


def features_toml(plan: FeaturePlan) -> str:
    """The plan as the file's text (load_features reads it back equal)."""
    out = [
        f'format = "{FORMAT}"',
        f"part = {_q(plan.part)}",
        f"description = {_q(plan.description)}",
    ]
    if plan.clamp_sd_mm > 0:
        out.append(f"clamp_sd_mm = {plan.clamp_sd_mm:g}")
    for f in plan.features:
        out += ["", "[[feature]]", f"id = {_q(f.id)}", f"type = {_q(f.type)}"]
        out.append(f"position_mm = {_vec(f.position_mm)}")
        out.append(f"normal = {_vec(f.normal)}")
        if f.type == "slot":
            out.append(f"axis = {_vec(f.axis)}")
        for name, v in zip(_SIZES[f.type], f.size_mm, strict=True):
            out.append(f"{name} = {v:g}")
        out.append(f"thickness_mm = {f.thickness_mm:g}")
        for name, (lo, hi) in f.tolerances.items():
            out.append(f"{name} = [{lo:g}, {hi:g}]")
    return "\n".join(out) + "\n"


def _q(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _vec(v: F64) -> str:
    return "[" + ", ".join(f"{float(a):.6g}" for a in v) + "]"
