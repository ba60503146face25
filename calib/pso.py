"""Particle swarm optimisation (Kennedy & Eberhart 1995) with Clerc's constriction constants.

Minimises f over a box; f is evaluated for the whole swarm at once (so that the caller may
spread the evaluations over processes) and returns +inf where a position is infeasible.
Positions stay inside the box (clipped, with the velocity component reversed at a wall).
Seeded through the rng passed in. Optionally stops early, once the swarm's best has not
improved by more than a relative `tolerance` for `patience` iterations (a stopped run is the
first iterations of the full one: the same random stream).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class SwarmSettings:
    n_particles: int = 50
    n_iterations: int = 30
    inertia: float = 0.7298
    c_personal: float = 1.49618
    c_social: float = 1.49618
    v_max_fraction: float = 0.2
    #: Stop after this many iterations in a row without an improvement of the best by more
    #: than `tolerance` (relative) over the best when it last improved so; 0: never.
    patience: int = 0
    tolerance: float = 1e-3

    def __post_init__(self) -> None:
        if self.n_particles < 2:
            raise ValueError(f"swarm size {self.n_particles}: expected >= 2")
        if self.n_iterations < 1:
            raise ValueError(f"PSO iterations {self.n_iterations}: expected >= 1")
        if self.patience < 0:
            raise ValueError(f"PSO patience {self.patience}: expected >= 0 (0: off)")
        if not self.tolerance >= 0.0:
            raise ValueError(f"PSO tolerance {self.tolerance}: expected >= 0")


@dataclass(frozen=True)
class SwarmResult:
    x_best: F64
    f_best: float
    history: F64  # best value after the initial swarm and each iteration
    n_evaluations: int
    stopped_early: bool = False  # the best stalled for `patience` iterations


def minimize(
    f_batch: Callable[[F64], F64],
    lower: ArrayLike,
    upper: ArrayLike,
    rng: np.random.Generator,
    settings: SwarmSettings | None = None,
    *,
    initial: F64 | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> SwarmResult:
    """Minimise f_batch (P, d) -> (P,) over the box [lower, upper]; `initial` (P, d) positions
    (default uniform in the box); progress(iteration, n_iterations, best) after each step
    (progress(iteration, iteration, best) after the last one of a run stopped early)."""
    s = settings or SwarmSettings()
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    span = hi - lo
    x = rng.uniform(lo, hi, (s.n_particles, lo.size)) if initial is None else initial.copy()
    v_max = s.v_max_fraction * span
    v = rng.uniform(-v_max, v_max, x.shape)
    f = np.asarray(f_batch(x), dtype=float)
    p_best, f_pbest = x.copy(), f.copy()
    g = int(np.argmin(f_pbest))
    history = [float(f_pbest[g])]
    evaluations = x.shape[0]
    if progress:
        progress(0, s.n_iterations, history[-1])
    mark, stalled = history[-1], 0  # the best when it last improved by more than the tolerance
    for it in range(1, s.n_iterations + 1):
        r1, r2 = rng.random(x.shape), rng.random(x.shape)
        v = s.inertia * v + s.c_personal * r1 * (p_best - x) + s.c_social * r2 * (p_best[g] - x)
        v = np.clip(v, -v_max, v_max)
        x = x + v
        out = (x < lo) | (x > hi)
        v[out] *= -0.5
        x = np.clip(x, lo, hi)
        f = np.asarray(f_batch(x), dtype=float)
        evaluations += x.shape[0]
        better = f < f_pbest
        p_best[better], f_pbest[better] = x[better], f[better]
        g = int(np.argmin(f_pbest))
        history.append(float(f_pbest[g]))
        best = history[-1]
        if np.isfinite(best):
            if not np.isfinite(mark) or mark - best > s.tolerance * abs(mark):
                mark, stalled = best, 0
            else:
                stalled += 1
        stop = s.patience > 0 and stalled >= s.patience and it < s.n_iterations
        if progress:
            progress(it, it if stop else s.n_iterations, best)
        if stop:
            return SwarmResult(p_best[g].copy(), best, np.array(history), evaluations, True)
    return SwarmResult(p_best[g].copy(), float(f_pbest[g]), np.array(history), evaluations)
