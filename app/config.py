"""Cell configuration: read once from TOML into frozen, validated objects.

The embedded default is the simulated cell (spheres at the paper's Table 1 positions). A cell
file overrides any of its keys; unknown keys and wrong types are input errors naming the file,
the line and the field (`section.key`).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from calib.detmax import METHODS
from calib.model import SystemModel
from calib.observability import INDEX_NAMES
from calib.plan import PLACEMENTS
from calib.robot import JointLimits
from calib.transforms import apply, pose, rotvec_to_matrix

F64 = NDArray[np.float64]

PAPER_TABLE1_BASE_MM = {
    "P1": [-647.14, 1254.27, -289.37],
    "P2": [1742.87, 1138.35, -260.87],
    "P3": [1428.57, -1347.92, 102.31],
    "P4": [-704.45, -1265.87, 680.54],
}

DEFAULTS: dict[str, dict[str, Any]] = {
    "robot": {
        "model": "fanuc-m710ic50",
        "joint_lower_deg": [-180.0, -90.0, -160.0, -360.0, -125.0, -360.0],
        "joint_upper_deg": [180.0, 135.0, 280.0, 360.0, 125.0, 360.0],
    },
    "frames": {
        "part_base_xyz_mm": [1500.0, -2500.0, 700.0],
        "part_base_rotvec_deg": [0.0, 0.0, 90.0],
        "flange_sensor_xyz_mm": [0.0, -90.0, 160.0],
        "flange_sensor_rotvec_deg": [0.0, 0.0, 0.0],
    },
    "base_plate": {"x_min_mm": -750.0, "x_max_mm": 750.0, "y_min_mm": -750.0, "y_max_mm": 750.0},
    "sensor": {
        "standoff_mm": 130.0,
        "half_fov_x_mm": 18.5,
        "half_fov_y_mm": 13.5,
        "half_depth_mm": 5.0,
        "sphere_radius_mm": 15.0,
    },
    "spheres": {"frame": "base", "positions_mm": PAPER_TABLE1_BASE_MM},
    "simulation": {
        "seed": 0,
        "tracker_noise_mm": 0.01,
        "sensor_noise_mm": 0.02,
        "compliance": True,
        "thermal": True,
        "temp_c": 20.0,
    },
    "calibration": {"configs_per_sphere": 6, "loss": "linear", "max_rms_mm": 0.25},
    "planning": {
        "criterion": "O1",
        "method": "detmax",
        "placement": "sequential",
        "grid_step_deg": 5.0,
        "search_step_deg": 30.0,
        "max_tilt_deg": 80.0,
        "fov_offsets": "spread",
        "swarm_size": 50,
        "iterations": 30,
        "clearance_above_sphere_mm": 30.0,
        "floor_z_mm": -565.0,
        "clearance_above_floor_mm": 150.0,
        "workspace_mm": [-2000.0, 2000.0, -2000.0, 2000.0],
        "reach_mm": 2000.0,
        "plate_margin_mm": 50.0,
        "min_separation_mm": 300.0,
        "seed": 0,
        "workers": 2,
    },
    "devices": {
        "robot": "fake://",
        "camera": "fake://",
        "galvo": "fake://",
        "tracker": "fake://",
        "plc": "fake://",
    },
    "service": {"database": "rvis.sqlite"},
}


@dataclass(frozen=True)
class CellConfig:
    """The resolved cell: nominal frames, limits, spheres (part frame), settings."""

    T_part_base: F64
    T_flange_sensor: F64
    limits: JointLimits
    spheres_part_mm: dict[str, F64]
    base_plate_mm: tuple[float, float, float, float]
    sensor: dict[str, float]
    simulation: dict[str, Any]
    calibration: dict[str, Any]
    planning: dict[str, Any]
    devices: dict[str, str]
    service: dict[str, Any]
    source: str = "<embedded default>"
    raw: dict[str, dict[str, Any]] = field(default_factory=dict, repr=False)

    def model(self) -> SystemModel:
        """The nominal system model of this cell."""
        return SystemModel(self.T_part_base, self.T_flange_sensor, self.limits)


def _line_of(text: str, key: str) -> int | None:
    for n, line in enumerate(text.splitlines(), start=1):
        if re.match(rf"\s*{re.escape(key)}\s*=", line):
            return n
    return None


class _Reader:
    def __init__(self, merged: dict[str, dict[str, Any]], path: str, text: str) -> None:
        self.merged, self.path, self.text = merged, path, text

    def fail(self, section: str, key: str, reason: str) -> InputError:
        line = _line_of(self.text, key) if self.text else None
        return InputError(reason, file=self.path, line=line, field=f"{section}.{key}")

    def vector(self, section: str, key: str, n: int) -> F64:
        value = self.merged[section][key]
        ok = isinstance(value, list) and len(value) == n
        if not ok or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            raise self.fail(section, key, f"expected a list of {n} numbers")
        return np.array(value, dtype=float)

    def number(self, section: str, key: str) -> float:
        value = self.merged[section][key]
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise self.fail(section, key, f"expected a number, got {value!r}")
        return float(value)


def load_cell(path: str | Path | None = None) -> CellConfig:
    """The default cell, overridden by the TOML file at `path` if given."""
    merged = {k: dict(v) for k, v in DEFAULTS.items()}
    text, source = "", "<embedded default>"
    if path is not None:
        source = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
            user = tomllib.loads(text)
        except OSError as exc:
            raise InputError(f"cannot read file: {exc.strerror or exc}", file=path) from exc
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"invalid TOML: {exc}", file=path) from exc
        for section, values in user.items():
            if section not in merged or not isinstance(values, dict):
                raise InputError("unknown section", file=path, field=section)
            for key, value in values.items():
                if key not in merged[section]:
                    raise InputError(
                        "unknown key", file=path, line=_line_of(text, key), field=f"{section}.{key}"
                    )
                merged[section][key] = value
    return _resolve(_Reader(merged, source, text))


_PLAN_CHOICES = {
    "criterion": INDEX_NAMES,
    "method": METHODS,
    "placement": PLACEMENTS,
    "fov_offsets": ("spread", "centre"),
}
_PLAN_INTEGERS = {"swarm_size": 2, "iterations": 1, "seed": 0, "workers": 1}


def _planning(r: _Reader) -> dict[str, Any]:
    """The [planning] section, each value checked (choices, integers, numbers)."""
    out: dict[str, Any] = {}
    for key, value in r.merged["planning"].items():
        if key in _PLAN_CHOICES:
            if value not in _PLAN_CHOICES[key]:
                choices = ", ".join(_PLAN_CHOICES[key])
                raise r.fail("planning", key, f"expected one of {choices}, got {value!r}")
            out[key] = value
        elif key in _PLAN_INTEGERS:
            if not isinstance(value, int) or isinstance(value, bool) or value < _PLAN_INTEGERS[key]:
                raise r.fail("planning", key, f"expected an integer >= {_PLAN_INTEGERS[key]}")
            out[key] = value
        elif key == "workspace_mm":
            box = r.vector("planning", key, 4)
            if box[0] >= box[1] or box[2] >= box[3]:
                raise r.fail("planning", key, "expected [x_min, x_max, y_min, y_max], min < max")
            out[key] = tuple(float(v) for v in box)
        else:
            out[key] = r.number("planning", key)
    step = out["grid_step_deg"]
    if not 0.0 < step <= 90.0 or not 0.0 < out["search_step_deg"] <= 90.0:
        raise r.fail("planning", "grid_step_deg", "grid steps must lie in (0, 90] deg")
    if not 0.0 <= out["max_tilt_deg"] <= 90.0:
        raise r.fail(
            "planning", "max_tilt_deg", "the view must not point upward: 0..90 deg from down"
        )
    return out


def _resolve(r: _Reader) -> CellConfig:
    m = r.merged
    lower = r.vector("robot", "joint_lower_deg", 6)
    upper = r.vector("robot", "joint_upper_deg", 6)
    if np.any(lower >= upper):
        raise r.fail("robot", "joint_upper_deg", "every upper limit must exceed its lower limit")
    T_pb = pose(
        rotvec_to_matrix(np.radians(r.vector("frames", "part_base_rotvec_deg", 3))),
        r.vector("frames", "part_base_xyz_mm", 3),
    )
    T_fs = pose(
        rotvec_to_matrix(np.radians(r.vector("frames", "flange_sensor_rotvec_deg", 3))),
        r.vector("frames", "flange_sensor_xyz_mm", 3),
    )
    frame = m["spheres"]["frame"]
    if frame not in ("base", "part"):
        raise r.fail("spheres", "frame", f"expected 'base' or 'part', got {frame!r}")
    positions = m["spheres"]["positions_mm"]
    if not isinstance(positions, dict) or not positions:
        raise r.fail("spheres", "positions_mm", "expected a table of sphere ids -> [x, y, z]")
    spheres: dict[str, F64] = {}
    for tid, value in positions.items():
        if not (isinstance(value, list) and len(value) == 3):
            raise r.fail("spheres", "positions_mm", f"sphere {tid}: expected [x, y, z] in mm")
        p = np.array(value, dtype=float)
        spheres[str(tid)] = apply(T_pb, p) if frame == "base" else p
    plate = tuple(
        r.number("base_plate", k) for k in ("x_min_mm", "x_max_mm", "y_min_mm", "y_max_mm")
    )
    sensor = {k: r.number("sensor", k) for k in m["sensor"]}
    planning = _planning(r)
    devices = {k: str(v) for k, v in m["devices"].items()}
    return CellConfig(
        T_part_base=T_pb,
        T_flange_sensor=T_fs,
        limits=JointLimits(lower, upper),
        spheres_part_mm=spheres,
        base_plate_mm=plate,  # type: ignore[arg-type]
        sensor=sensor,
        simulation=dict(m["simulation"]),
        calibration=dict(m["calibration"]),
        planning=planning,
        devices=devices,
        service=dict(m["service"]),
        source=r.path,
        raw=m,
    )
