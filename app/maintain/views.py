"""The plan's views in a maintenance procedure: read from the procedure's copy of the plan and
re-aimed on the parameters so far at the spheres' places now (app.maintain.aim)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.context import Context
from app.commission.files import PARAMS_BEFORE_FILE, PLAN_FILE
from app.formats.params import from_json
from app.maintain.aim import reaim
from app.planning import read_plan

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Views:
    """The plan's views: sphere of each, planned configuration (K, 6), planned centre (K, 3)."""

    targets: tuple[str, ...]
    q_deg: F64
    c_mm: F64

    @staticmethod
    def of_plan(ctx: Context) -> Views:
        _, qs, cs = read_plan(ctx.path(PLAN_FILE))
        targets = tuple(t for t, q in qs.items() for _ in range(len(q)))
        return Views(targets, np.vstack(list(qs.values())), np.vstack(list(cs.values())))

    def pick(self, ks: list[int]) -> Views:
        """The views ks of these, in that order."""
        return Views(tuple(self.targets[k] for k in ks), self.q_deg[ks], self.c_mm[ks])


def rigid_share(ctx: Context, x: F64) -> tuple[Any, F64]:
    """The rigid chain the plan was made on, and x's share of it."""
    model = ctx.cell().model()
    return model, np.asarray(x, dtype=float)[: len(model.nominal_x())]


def aimed(ctx: Context, views: Views, x_now: F64) -> tuple[F64, np.ndarray]:
    """The views re-aimed on x_now at the spheres' places now (TARGETS_FILE)."""
    _, x_plan = from_json(ctx.path(PARAMS_BEFORE_FILE))
    model, xp = rigid_share(ctx, x_plan)
    _, xn = rigid_share(ctx, x_now)
    p_now = ctx.spheres_part_mm()
    p = np.array([p_now[t] for t in views.targets])
    return reaim(model, xp, xn, views.q_deg, views.c_mm, p)
