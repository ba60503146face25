"""The robot's motion-time model: how long one joint move takes (the slowest joint at its maximum
speed x speed x override, plus the acceleration and settling allowances; REFERENCE.md "In-line
operation"), and the shortest route through configurations by it. The schedule's windows, a
maintenance procedure's views and a body's route are timed and ordered by it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from app.config.line import LineSettings


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
