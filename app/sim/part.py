"""The simulated line's part type: a body side's sheet-metal features in the inspection
workspace (DESIGN.md section 14), as a feature plan, and the bridge to the simulated bodies.

`default_part(cfg)` lays 24 features (10 round holes of 6-20 mm, 5 slots up to 10 x 25 mm, 9
surface points) on patches across the body's side of the workspace (900-1900 mm from the J1 axis,
-200..500 mm high, robot base frame), each sheet facing the robot and tilted up 20-55 degrees as
a body's side and sills are, 0.7-1.2 mm thick; tolerances as a body shop writes them (position
+-0.5 mm, size +-0.2 mm, surface along the normal +-0.7 mm). The layout is drawn from a fixed
stream, so every simulated cell of a configuration has the same part type.

`nominal_features(plan)` hands the plan to the simulated world as plain numbers (fakes.body's
NominalFeature: fakes/ never reads the plan's file).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.formats.files import write_text
from app.inspect.plan import Feature, FeaturePlan, features_toml
from app.line.statedir import StateDir
from fakes.body import ClampSettings, NominalFeature

F64 = NDArray[np.float64]
PART_NUMBER = "SIM-BIW-01"
#: the layout's random stream (fixed: one part type per cell configuration)
LAYOUT_STREAM = (48, 1)
TOLERANCES = {
    "position_tol_mm": (-0.5, 0.5),
    "size_tol_mm": (-0.2, 0.2),
    "normal_tol_mm": (-0.7, 0.7),
}
PREFIX = {"hole": "H", "slot": "S", "surface": "P"}
KINDS = ("hole",) * 10 + ("slot",) * 5 + ("surface",) * 9


def default_part(cfg: CellConfig) -> FeaturePlan:
    """The simulated part type of the cell (module docstring)."""
    rng = np.random.default_rng(LAYOUT_STREAM)
    R_pb, t_pb = cfg.T_part_base[:3, :3], cfg.T_part_base[:3, 3]
    features: list[Feature] = []
    n = len(KINDS)
    # along the body: the features spread over a 100-degree arc of the robot's side
    angles = np.radians(np.linspace(-50.0, 50.0, n)) + rng.normal(0.0, 0.02, n)
    order = rng.permutation(n)
    counters = {"hole": 0, "slot": 0, "surface": 0}
    for i, kind in enumerate(KINDS):
        a = angles[order[i]]
        r, z = rng.uniform(1150.0, 1650.0), rng.uniform(-200.0, 500.0)
        p_base = np.array([r * np.cos(a), r * np.sin(a), z])
        tilt = np.radians(rng.uniform(20.0, 55.0))
        towards = -np.array([np.cos(a), np.sin(a), 0.0])
        n_base = np.cos(tilt) * towards + np.array([0.0, 0.0, np.sin(tilt)])
        axis_base = np.cross(n_base, [0.0, 0.0, 1.0])
        axis_base /= np.linalg.norm(axis_base)
        counters[kind] += 1
        fid = f"{PREFIX[kind]}{counters[kind]:02d}"
        size: tuple[float, ...] = ()
        if kind == "hole":
            size = (float(rng.choice([6.0, 8.0, 10.0, 12.0, 16.0, 20.0])),)
        elif kind == "slot":
            w = float(rng.choice([6.0, 8.0, 10.0]))
            size = (w, float(rng.choice([14.0, 18.0, 22.0, 25.0])))
        tols = {k: v for k, v in TOLERANCES.items() if _uses(kind, k)}
        features.append(
            Feature(
                fid,
                kind,
                np.round(R_pb @ p_base + t_pb, 3),
                np.round(R_pb @ n_base, 6),
                np.round(R_pb @ axis_base, 6) if kind == "slot" else np.zeros(3),
                size,
                float(rng.choice([0.7, 0.8, 1.0, 1.2])),
                tols,
            )
        )
    return FeaturePlan(
        PART_NUMBER,
        "simulated body side, 24 features",
        tuple(features),
        clamp_sd_mm=clamp_sd_mm(np.array([f.position_mm for f in features]), ClampSettings()),
    )


def clamp_sd_mm(p_mm: F64, s: ClampSettings) -> float:
    """The simulated fixture's clamping repeatability at features p_mm (n, 3), one standard
    deviation per axis [mm], as a plant states its fixture's (the feature plan's
    `clamp_sd_mm`): the translation's, and the rotation about the features' centroid at their
    RMS distance from it (a rotation of sd r per axis moves a point at distance L by r L
    sqrt(2/3) per axis on average)."""
    lever = float(np.sqrt(np.mean(np.sum((p_mm - p_mm.mean(axis=0)) ** 2, axis=1))))
    rot = s.rotation_sd_rad * lever * float(np.sqrt(2.0 / 3.0))
    return round(float(np.hypot(s.translation_sd_mm, rot)), 4)


def _uses(kind: str, tol: str) -> bool:
    if kind == "surface":
        return tol == "normal_tol_mm"
    return tol in ("position_tol_mm", "size_tol_mm")


def nominal_features(plan: FeaturePlan) -> list[NominalFeature]:
    """The plan's features for the simulated world (fakes.body), as plain numbers."""
    return [
        NominalFeature(f.id, f.type, f.position_mm, f.normal, f.axis, f.size_mm, f.thickness_mm)
        for f in plan.features
    ]


def ensure_features(state_root: Path, cfg: CellConfig) -> Path:
    """The state directory's feature plan: the simulated part type's written there when it has
    none (`rvis commission --sim`, `rvis run --sim`: the simulated line measures its bodies as a
    plant's cell would); a plan already there is kept."""
    path = StateDir(state_root).features
    if not path.is_file():
        write_text(path, features_toml(default_part(cfg)))
    return path
