"""The inspection workspace: where the system is used, and so where it is validated and what
the planner's criterion "I" (calib.ioptimal) weighs.

The region (`WORKSPACE`) is the car body's side of the cell: 900-1900 mm from the J1 axis,
-300..700 mm in height (robot base frame), outside the base plate. `workspace_points` draws
sphere positions spread over it (the validation positions of every simulated experiment);
the weight W of criterion "I" is the mean J_u^T J_u of the identification Jacobian's point
blocks at random reachable views of such positions, drawn from their own random stream (never
the validation set's).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.errors import InputError
from calib.candidates import random_configurations
from calib.ioptimal import workspace_weight
from calib.model import SystemModel

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class WorkspaceRegion:
    """Where the system inspects: an annulus about the J1 axis [mm] and a height band [mm],
    robot base frame."""

    r_mm: tuple[float, float] = (900.0, 1900.0)
    z_mm: tuple[float, float] = (-300.0, 700.0)


WORKSPACE = WorkspaceRegion()
#: Workspace positions whose views make up W (one view each); enough that W's spread
#: between streams is small beside the differences between plans.
N_POSITIONS = 300
#: The random stream's second key (the first is the planning seed).
STREAM = 11


def workspace_points(
    cfg: CellConfig, n: int, rng: np.random.Generator, region: WorkspaceRegion = WORKSPACE
) -> dict[str, F64]:
    """n sphere positions (part frame) spread uniformly in radius, angle and height over the
    workspace region, outside the base plate, named V001..; InputError when the plate covers
    the region."""
    x0, x1, y0, y1 = cfg.base_plate_mm
    out: dict[str, F64] = {}
    for _ in range(1000 * n):
        if len(out) == n:
            break
        r, a, z = rng.uniform(*region.r_mm), rng.uniform(-np.pi, np.pi), rng.uniform(*region.z_mm)
        p_base = np.array([r * np.cos(a), r * np.sin(a), z])
        if x0 <= p_base[0] <= x1 and y0 <= p_base[1] <= y1:
            continue
        out[f"V{len(out) + 1:03d}"] = cfg.T_part_base[:3, :3] @ p_base + cfg.T_part_base[:3, 3]
    if len(out) < n:
        lo, hi = region.r_mm
        raise InputError(
            f"[base_plate]: the plate covers the workspace ({lo:g}-{hi:g} mm from the J1 axis)",
            file=cfg.source,
        )
    return out


def workspace_views(
    cfg: CellConfig, model: SystemModel, x: F64, n: int, rng: np.random.Generator
) -> tuple[F64, F64]:
    """(q_deg (k, 6), c_sensor_mm (k, 3)): one random reachable view at each of n workspace
    positions (k <= n: positions without a reachable view are left out)."""
    qs, cs = [], []
    for p in workspace_points(cfg, n, rng).values():
        v = random_configurations(model, x, p, 1, rng)
        if len(v.q_deg):
            qs.append(v.q_deg[0])
            cs.append(v.c_planned_mm[0])
    return np.array(qs).reshape(-1, 6), np.array(cs).reshape(-1, 3)


def weight_for(
    cfg: CellConfig,
    model: SystemModel,
    x: F64,
    active: Sequence[str],
    seed: int,
    n: int = N_POSITIONS,
) -> F64:
    """The workspace weight W (L, L) on parameters x for the `active` parameters."""
    q, c = workspace_views(cfg, model, x, n, np.random.default_rng([seed, STREAM]))
    return workspace_weight(model.point_jacobian(x, q, c, active))
