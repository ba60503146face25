"""The measurement schedule: the plan's configurations, cycled, and the slot that fits a window.

Slots interleave the spheres (S1 c1, S2 c1, ..., S1 c2, ...) so consecutive windows see
different spheres. The position of the next slot is stored with every measurement (store.py),
so the service resumes where it stopped after a restart. A slot fits when the estimated time of
moving there, measuring and coming home is within the remaining window less a margin; the
motion time of a joint move is set by the slowest joint at its maximum speed x speed x
override, plus the acceleration and settling allowances (REFERENCE.md "In-line operation").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.config.line import LineSettings

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Slot:
    """Position `index` of the schedule: measure sphere `target` from `q_deg` (controller
    angles [deg], shape (6,))."""

    index: int
    target: str
    q_deg: F64


def motion_time_s(start_deg: ArrayLike, end_deg: ArrayLike, line: LineSettings) -> float:
    """Estimated time of one joint move [s]; 0 when there is nothing to move."""
    delta = np.abs(np.asarray(end_deg, float) - np.asarray(start_deg, float))
    if float(np.max(delta)) <= line.home_tol_deg:
        return 0.0
    scale = line.speed_pct / 100.0 * line.override_pct / 100.0
    speed = np.asarray(line.joint_speed_deg_s) * scale
    return float(np.max(delta / speed)) + line.accel_s + line.settle_s


def shortest_route(
    q_deg: Sequence[ArrayLike], start_deg: ArrayLike, line: LineSettings
) -> list[int]:
    """The order [indices] in which to visit the configurations q_deg from start_deg and back
    to it with the least motion time (`motion_time_s`): the nearest one next, then 2-opt
    (reversing a stretch of the route while that shortens it). For the handful of views a
    maintenance procedure measures view to view: their plan order crosses the workspace."""
    points = [np.asarray(start_deg, dtype=float)] + [np.asarray(q, dtype=float) for q in q_deg]
    n = len(points)
    cost = np.array([[motion_time_s(a, b, line) for b in points] for a in points])
    route, left = [0], set(range(1, n))
    while left:
        nearest = min(left, key=lambda j: (cost[route[-1], j], j))
        route.append(nearest)
        left.remove(nearest)
    route.append(0)
    improved = True
    while improved:
        improved = False
        for i in range(1, n - 1):
            for k in range(i + 1, n):
                a, b, c, d = route[i - 1], route[i], route[k], route[k + 1]
                if cost[a, c] + cost[b, d] < cost[a, b] + cost[c, d] - 1e-9:
                    route[i : k + 1] = route[i : k + 1][::-1]
                    improved = True
    return [j - 1 for j in route[1:-1]]


class Schedule:
    """The plan's configurations in cycle order."""

    def __init__(self, q_by_target: Mapping[str, ArrayLike], line: LineSettings) -> None:
        qs = {t: np.asarray(q, dtype=np.float64).reshape(-1, 6) for t, q in q_by_target.items()}
        order: list[tuple[str, F64]] = []
        for k in range(max((len(q) for q in qs.values()), default=0)):
            order += [(t, q[k]) for t, q in qs.items() if k < len(q)]
        if not order:
            raise ValueError("the plan holds no configuration")
        self.slots = tuple(Slot(i, t, q) for i, (t, q) in enumerate(order))
        self.line = line
        self.home_deg = np.array(line.home_deg, dtype=np.float64)

    @classmethod
    def from_plan(cls, path: str | Path, line: LineSettings) -> Schedule:
        """The schedule of a plan file written by `rvis plan` (InputError when malformed)."""
        from app.planning import read_plan

        _, q_by_target, _ = read_plan(path)
        return cls(q_by_target, line)

    def __len__(self) -> int:
        return len(self.slots)

    @property
    def targets(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(s.target for s in self.slots))

    def slot_time_s(self, current_deg: ArrayLike, slot: Slot, sensor_s: float) -> float:
        """Move from `current_deg` to the slot, measure, and come home [s]."""
        there = motion_time_s(current_deg, slot.q_deg, self.line)
        return there + sensor_s + motion_time_s(slot.q_deg, self.home_deg, self.line)

    def next_fitting(
        self,
        position: int,
        current_deg: ArrayLike,
        remaining_s: float,
        sensor_s: float,
        choose: Callable[[Sequence[Slot]], Slot] | None = None,
    ) -> Slot | None:
        """The first slot from `position` on (cyclically) that fits in `remaining_s` less the
        margin, or None when none does; with `choose` (adaptive scheduling), its pick among
        every slot that fits."""
        budget = remaining_s - self.line.margin_s
        n = len(self.slots)
        order = [self.slots[(position + k) % n] for k in range(n)]
        fitting = (s for s in order if self.slot_time_s(current_deg, s, sensor_s) <= budget)
        if choose is None:
            return next(fitting, None)
        pool = list(fitting)
        return choose(pool) if pool else None
