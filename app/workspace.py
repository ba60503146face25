"""The inspection workspace as the planner's criterion "I" sees it (calib.ioptimal).

The system is used, and validated, at sphere positions spread over the workspace (the region
of `app.simulation.validation_points`: 900-1900 mm from the J1 axis, -300..700 mm in height,
outside the base plate), each seen from a random reachable view. The weight W of the
criterion is the mean J_u^T J_u of the identification Jacobian's point blocks at such views,
drawn from their own random stream (never the validation set's).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.simulation import validation_points
from calib.candidates import random_configurations
from calib.ioptimal import workspace_weight
from calib.model import SystemModel

F64 = NDArray[np.float64]
#: Workspace positions whose views make up W (one view each); enough that W's spread
#: between streams is small beside the differences between plans.
N_POSITIONS = 300
#: The random stream's second key (the first is the planning seed).
STREAM = 11


def workspace_views(
    cfg: CellConfig, model: SystemModel, x: F64, n: int, rng: np.random.Generator
) -> tuple[F64, F64]:
    """(q_deg (k, 6), c_sensor_mm (k, 3)): one random reachable view at each of n workspace
    positions (k <= n: positions without a reachable view are left out)."""
    qs, cs = [], []
    for p in validation_points(cfg, n, rng).values():
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
