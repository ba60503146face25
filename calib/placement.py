"""Where the spheres stand (paper section 4.4): particle swarm optimisation (calib.pso) of each
sphere's (x, y) in the robot base frame with its height fixed, inside the feasible region
(outside the base plate: the paper's Eqs. 17-18), one sphere after the other as in the paper or
all four jointly. The fitness is minus the criterion index of all configurations chosen so far,
on a coarse orientation grid (`PlanSettings.search_grid`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.configurations import (
    candidate_blocks,
    candidate_blocks_of_many,
    choose,
    choose_from,
    plan_index,
    reachable_rank,
    stage_settings,
)
from calib.errors import NoCandidates
from calib.model import SystemModel
from calib.plan_settings import F64, FeasibleRegion, MapFn, PlanSettings, Progress
from calib.pso import minimize
from calib.transforms import apply

#: Particles per block of the swarm's map: one Jacobian call per block, and blocks small
#: enough that the processes share the swarm evenly.
PARTICLE_BLOCK = 5


def part_from_base(model: SystemModel, x: F64, xy: F64, z_base_mm: float) -> F64:
    return apply(model.T_part_base(x), np.array([xy[0], xy[1], z_base_mm]))


@dataclass(frozen=True)
class Fitness:
    """Picklable fitness of particles (for process pools): minus the index of all chosen
    configurations for spheres at the particle's x-y (one sphere, or all for the joint
    placement), +inf where infeasible or unreachable."""

    model: SystemModel
    x: F64
    z_base_mm: tuple[float, ...]
    placed_xy_mm: F64  # (k, 2) spheres placed before (their blocks in J_fixed)
    J_fixed: F64
    settings: PlanSettings
    region: FeasibleRegion
    rank: int

    def _feasible(self, xy: F64) -> bool:
        if not np.all(self.region.contains(xy)):
            return False
        every = np.concatenate([self.placed_xy_mm, xy])
        gaps = np.linalg.norm(every[:, None, :] - every[None, :, :], axis=2)
        return not np.any(gaps[np.triu_indices(len(every), 1)] < self.settings.min_separation_mm)

    def block(self, particles: F64) -> F64:
        """The fitness of a block of particles (k, 2 n_spheres): with one sphere per particle
        (the sequential placement) one Jacobian call for the candidates of the whole block;
        the same values as particle by particle."""
        P = np.atleast_2d(np.asarray(particles, dtype=float))
        if len(self.z_base_mm) != 1:
            return np.array([self(p) for p in P])
        out = np.full(len(P), np.inf)
        ok = [i for i in range(len(P)) if self._feasible(P[i].reshape(-1, 2))]
        if not ok:
            return out
        z = self.z_base_mm[0]
        points = [part_from_base(self.model, self.x, P[i], z) for i in ok]
        blocks = candidate_blocks_of_many(
            self.model, self.x, points, self.settings.search_grid, self.settings
        )
        for i, (cand, J) in zip(ok, blocks, strict=True):
            try:
                _, J_sel, _ = choose_from(cand, J, self.J_fixed, self.settings, polish=False)
            except NoCandidates:
                continue
            J_all = np.concatenate([self.J_fixed, J_sel])
            out[i] = -plan_index(J_all, self.settings.criterion, self.rank, self.settings.weight)
        return out

    def __call__(self, particle: F64) -> float:
        xy = np.asarray(particle, dtype=float).reshape(-1, 2)
        if not self._feasible(xy):
            return float("inf")
        J = self.J_fixed
        grid = self.settings.search_grid
        try:
            for (px, py), z in zip(xy, self.z_base_mm, strict=True):
                p = part_from_base(self.model, self.x, np.array([px, py]), z)
                _, J_sel, _ = choose(self.model, self.x, p, grid, J, self.settings, polish=False)
                J = np.concatenate([J, J_sel])
        except NoCandidates:
            return float("inf")
        return -plan_index(J, self.settings.criterion, self.rank, self.settings.weight)


def swarm(
    fitness: Fitness,
    region: FeasibleRegion,
    n_spheres: int,
    initial_xy: F64,
    stage: str,
    progress: Progress | None,
    map_fn: MapFn,
) -> tuple[F64, F64]:
    s = fitness.settings
    rng = np.random.default_rng([s.seed, n_spheres, len(fitness.placed_xy_mm)])
    bx0, bx1, by0, by1 = region.box_mm
    lower = np.tile([bx0, by0], n_spheres)
    upper = np.tile([bx1, by1], n_spheres)
    start = region.sample(rng, s.swarm.n_particles * n_spheres).reshape(s.swarm.n_particles, -1)
    start[0] = initial_xy.reshape(-1)  # the current positions are one of the particles

    def f_batch(particles: F64) -> F64:
        blocks = [
            particles[i : i + PARTICLE_BLOCK] for i in range(0, len(particles), PARTICLE_BLOCK)
        ]
        return np.concatenate([np.asarray(v, dtype=float) for v in map_fn(fitness.block, blocks)])

    def report(it: int, n_it: int, best: float) -> None:
        if progress:
            progress(stage, it, n_it, -best)

    res = minimize(f_batch, lower, upper, rng, s.swarm, initial=start, progress=report)
    if not np.isfinite(res.f_best):
        raise NoCandidates(
            f"{stage}: no particle of the swarm found a feasible, reachable position "
            f"({res.n_evaluations} evaluated)"
        )
    return res.x_best.reshape(n_spheres, 2), -res.history


def fitness(
    model: SystemModel,
    x: F64,
    z_base: tuple[float, ...],
    placed_xy: F64,
    J_fixed: F64,
    s: PlanSettings,
    region: FeasibleRegion,
    xy_start: F64,
) -> Fitness:
    """The fitness of a stage, with the rank reachable from the start position."""
    J_pool = [J_fixed]
    for (px, py), z in zip(np.reshape(xy_start, (-1, 2)), z_base, strict=True):
        _, J = candidate_blocks(
            model, x, part_from_base(model, x, np.array([px, py]), z), s.search_grid, s
        )
        J_pool.append(J)
    pool = np.concatenate(J_pool)
    rank = reachable_rank(np.zeros((0, 3, pool.shape[2])), pool) if len(pool) else len(s.active)
    s = stage_settings(s, rank)
    return Fitness(model, x, z_base, np.asarray(placed_xy).reshape(-1, 2), J_fixed, s, region, rank)
