"""Measurement planning: where the spheres stand and from which configurations the robot
measures them (paper section 4, Fig. 6).

For a sphere position: the candidate configurations on an orientation grid (calib.candidates),
their identification-Jacobian blocks on the pre-calibrated model, and DETMAX (calib.detmax)
choosing n of them together with the configurations already chosen for the other spheres.
Positions: particle swarm optimisation (calib.pso) of each sphere's (x, y) in the robot base
frame with its height fixed, inside the feasible region (outside the base plate: the paper's
Eqs. 17-18), either one sphere after the other as in the paper or all four jointly. The
fitness is minus the criterion index of all configurations chosen so far.

Coarse to fine: the swarm's fitness uses a coarse orientation grid (`search_grid`); the final
configurations at the chosen positions come from the full grid (`grid`, default 5 degrees).
With the sequential placement they are chosen once per sphere, right after its swarm, and are
the fixed configurations of the next swarm (the full-grid choice is the costly serial stage:
110k-140k candidates; `PlanSettings.threads` spreads its sweeps over threads).

Partial plans: while fewer spheres are placed the Jacobian cannot reach rank L (one sphere
gives at most 27 of the 30 directions, two 29), so the fitness takes the r largest singular
values of the column-scaled Jacobian, r the rank that the fixed configurations and the whole
candidate pool reach together; with four spheres r = L and the index is the usual one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import detmax
from calib.candidates import (
    Candidates,
    Clearance,
    ViewGrid,
    random_configurations,
    sphere_candidates,
)
from calib.errors import EmptyRegion, NoCandidates
from calib.ik_refine import refine
from calib.ioptimal import check_weight, i_index
from calib.model import BASE_NAMES, INDEX, PAPER_30, SENSOR_NAMES, SystemModel
from calib.observability import (
    Observability,
    column_scaled,
    index_from_singular_values,
    observability,
)
from calib.pso import SwarmSettings, minimize
from calib.transforms import apply, inverse

F64 = NDArray[np.float64]
PLACEMENTS = ("sequential", "joint", "fixed")
#: Progress callback: (stage, step, steps, best fitness so far).
Progress = Callable[[str, int, int, float], None]
#: A map over blocks of particles (k, d) -> fitness values (k,), e.g. a process pool's `map`
#: (default: the builtin).
MapFn = Callable[[Callable[[F64], F64], Iterable[F64]], Iterable[F64]]
#: Particles per block of the swarm's map: one Jacobian call per block, and blocks small
#: enough that the processes share the swarm evenly.
PARTICLE_BLOCK = 5


@dataclass(frozen=True)
class FeasibleRegion:
    """Where a sphere may stand, x-y in the robot base frame [mm]: inside `box_mm`
    (x_min, x_max, y_min, y_max), within `r_max_mm` of the J1 axis, and outside the base plate
    `plate_mm` grown by `plate_margin_mm` (the paper's regions Q1 and Q2)."""

    plate_mm: tuple[float, float, float, float] = (-750.0, 750.0, -750.0, 750.0)
    box_mm: tuple[float, float, float, float] = (-2000.0, 2000.0, -2000.0, 2000.0)
    r_max_mm: float = 2000.0
    plate_margin_mm: float = 50.0

    def contains(self, xy_mm: ArrayLike) -> NDArray[np.bool_]:
        xy = np.atleast_2d(np.asarray(xy_mm, dtype=float))
        x, y = xy[:, 0], xy[:, 1]
        bx0, bx1, by0, by1 = self.box_mm
        px0, px1, py0, py1 = self.plate_mm
        m = self.plate_margin_mm
        in_box = (x >= bx0) & (x <= bx1) & (y >= by0) & (y <= by1)
        in_reach = np.hypot(x, y) <= self.r_max_mm
        on_plate = (x > px0 - m) & (x < px1 + m) & (y > py0 - m) & (y < py1 + m)
        ok: NDArray[np.bool_] = in_box & in_reach & ~on_plate
        return ok

    def sample(self, rng: np.random.Generator, n: int) -> F64:
        """n uniform positions (n, 2) in the region; EmptyRegion when it holds nothing."""
        bx0, bx1, by0, by1 = self.box_mm
        out: list[F64] = []
        for _ in range(100):
            xy = rng.uniform([bx0, by0], [bx1, by1], (max(4 * n, 1000), 2))
            out.extend(xy[self.contains(xy)])
            if len(out) >= n:
                return np.array(out[:n])
        raise EmptyRegion(
            f"the feasible region for the spheres is empty: box {self.box_mm} mm, reach "
            f"{self.r_max_mm} mm, base plate {self.plate_mm} mm + {self.plate_margin_mm} mm"
        )


@dataclass(frozen=True)
class PlanSettings:
    n_per_sphere: int = 6
    criterion: str = "O1"
    method: str = "detmax"
    placement: str = "sequential"
    grid: ViewGrid = field(default_factory=ViewGrid)
    search_grid: ViewGrid = field(default_factory=lambda: ViewGrid(step_deg=30.0))
    swarm: SwarmSettings = field(default_factory=SwarmSettings)
    clearance: Clearance = field(default_factory=Clearance)
    min_separation_mm: float = 300.0
    active: tuple[str, ...] = PAPER_30
    seed: int = 0
    #: Threads for the final choice of each sphere on the full grid (a serial stage: the
    #: swarm's processes wait for it). The result does not depend on it.
    threads: int = 1
    #: Passes over the spheres after the placement, each re-choosing a sphere's
    #: configurations given all the others (block coordinate ascent of the criterion; the
    #: sequential choice of the first spheres knew nothing of the later ones).
    revisits: int = 0
    #: The workspace weight W (L, L) of criterion "I" (calib.ioptimal), for `active`.
    weight: F64 | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        detmax.check_criterion(self.criterion)  # "I" checks its weight where it is used
        detmax.check_method(self.method)
        if self.placement not in PLACEMENTS:
            raise ValueError(
                f"unknown placement '{self.placement}' (choose from {', '.join(PLACEMENTS)})"
            )
        if self.n_per_sphere < 1:
            raise ValueError(f"configurations per sphere {self.n_per_sphere}: expected >= 1")
        if self.threads < 1:
            raise ValueError(f"threads {self.threads}: expected >= 1")
        if self.revisits < 0:
            raise ValueError(f"revisits {self.revisits}: expected >= 0")


@dataclass(frozen=True)
class SpherePlan:
    """One sphere: its centre (part frame), the chosen configurations q_deg (n, 6) and where
    the sphere appears in the field of view from each, c_sensor_mm (n, 3)."""

    name: str
    p_part_mm: F64
    q_deg: F64
    c_sensor_mm: F64
    n_candidates: int
    n_unrefined: int = 0  # configurations the refinement on the model did not converge for


@dataclass(frozen=True)
class Plan:
    spheres: tuple[SpherePlan, ...]
    observability: Observability
    random_observability: Observability
    random_q_deg: dict[str, F64]
    random_c_sensor_mm: dict[str, F64]
    settings: PlanSettings
    fitness_history: dict[str, F64]
    seconds: dict[str, float]

    def q_by_sphere(self) -> dict[str, F64]:
        return {s.name: s.q_deg for s in self.spheres}

    def positions_part_mm(self) -> dict[str, F64]:
        return {s.name: s.p_part_mm for s in self.spheres}


# -- one sphere --------------------------------------------------------------------------
def candidate_blocks(
    model: SystemModel,
    x: F64,
    p_part_mm: F64,
    grid: ViewGrid,
    settings: PlanSettings,
    threads: int = 1,
) -> tuple[Candidates, F64]:
    """Candidates of a sphere and their Jacobian blocks (M, 3, L), on `threads` threads."""
    cand = sphere_candidates(model, x, p_part_mm, grid, clearance=settings.clearance)
    n = len(cand)
    if threads < 2 or n < 4096:
        return cand, model.point_jacobian(x, cand.q_deg, cand.c_sensor_mm, settings.active)
    J = np.empty((n, 3, len(settings.active)))
    parts = np.array_split(np.arange(n), threads)

    def part(rows: NDArray[np.intp]) -> None:
        J[rows[0] : rows[-1] + 1] = model.point_jacobian(
            x, cand.q_deg[rows], cand.c_sensor_mm[rows], settings.active
        )

    with ThreadPoolExecutor(max_workers=threads) as pool:
        list(pool.map(part, parts))
    return cand, J


def choose(
    model: SystemModel,
    x: F64,
    p_part_mm: F64,
    grid: ViewGrid,
    J_fixed: F64,
    settings: PlanSettings,
    *,
    polish: bool = True,
    threads: int = 1,
) -> tuple[Candidates, F64, int]:
    """The n configurations of one sphere chosen with the fixed blocks, their blocks and the
    number of candidates; NoCandidates when fewer than n views are reachable."""
    cand, J = candidate_blocks(model, x, p_part_mm, grid, settings, threads)
    return _choose_from(cand, J, J_fixed, settings, polish=polish, threads=threads)


def _choose_from(
    cand: Candidates,
    J: F64,
    J_fixed: F64,
    settings: PlanSettings,
    *,
    polish: bool = True,
    threads: int = 1,
) -> tuple[Candidates, F64, int]:
    """`choose` on candidates and blocks at hand."""
    if len(cand) < settings.n_per_sphere:
        raise NoCandidates(
            f"sphere at {np.round(cand.p_part_mm, 1).tolist()} mm (part frame): {len(cand)} "
            f"reachable views that keep the clearance, {settings.n_per_sphere} needed"
        )
    rng = np.random.default_rng(settings.seed)
    sel = detmax.select(
        J,
        settings.n_per_sphere,
        rng,
        J_fixed=J_fixed,
        criterion=settings.criterion,
        method=settings.method,
        polish=polish,
        threads=threads,
        weight=settings.weight,
    )
    return cand.take(sel.indices), J[sel.indices], len(cand)


def _candidate_blocks_of_many(
    model: SystemModel, x: F64, points_part_mm: list[F64], grid: ViewGrid, settings: PlanSettings
) -> list[tuple[Candidates, F64]]:
    """`candidate_blocks` of several spheres with one Jacobian call for all their candidates
    (the rows are independent: the same blocks; on the swarm's ~500 candidates per sphere
    numpy's cost per call dominates)."""
    cands = [sphere_candidates(model, x, p, grid, clearance=settings.clearance)
             for p in points_part_mm]  # fmt: skip
    q = np.concatenate([c.q_deg for c in cands])
    c_sensor = np.concatenate([c.c_sensor_mm for c in cands])
    J = model.point_jacobian(x, q, c_sensor, settings.active)
    ends = np.cumsum([len(c) for c in cands])[:-1]
    return list(zip(cands, np.split(J, ends), strict=True))


def plan_index(
    J_blocks: F64, name: str, rank: int | None = None, weight: F64 | None = None
) -> float:
    """The index `name` of configuration blocks (K, 3, L) from their r largest singular
    values (r = rank, default L), column-scaled as calib.observability states; "I" from the
    r largest eigen-directions with the workspace weight (calib.ioptimal)."""
    if name == "I":
        return i_index(J_blocks, check_weight(weight, J_blocks.shape[2]), rank)
    K, _, L = J_blocks.shape
    Js, _ = column_scaled(J_blocks.reshape(-1, L))
    sigma = np.linalg.svd(Js, compute_uv=False)
    r = L if rank is None else rank
    sigma = np.concatenate([sigma, np.zeros(max(0, L - sigma.size))])[:r]
    sigma = np.maximum(sigma, 1e-9 * max(float(sigma[0]), 1e-300))
    return index_from_singular_values(name, sigma, K)


def _reachable_rank(J_fixed: F64, J_pool: F64) -> int:
    blocks = np.concatenate([J_fixed, J_pool])
    Js, _ = column_scaled(blocks.reshape(-1, blocks.shape[2]))
    lam = np.linalg.eigvalsh(Js.T @ Js)
    return max(1, int(np.sum(lam > 1e-12 * lam[-1])))


# -- positions ---------------------------------------------------------------------------
def _part_from_base(model: SystemModel, x: F64, xy: F64, z_base_mm: float) -> F64:
    return apply(model.T_part_base(x), np.array([xy[0], xy[1], z_base_mm]))


@dataclass(frozen=True)
class _Fitness:
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
        points = [_part_from_base(self.model, self.x, P[i], z) for i in ok]
        blocks = _candidate_blocks_of_many(
            self.model, self.x, points, self.settings.search_grid, self.settings
        )
        for i, (cand, J) in zip(ok, blocks, strict=True):
            try:
                _, J_sel, _ = _choose_from(cand, J, self.J_fixed, self.settings, polish=False)
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
                p = _part_from_base(self.model, self.x, np.array([px, py]), z)
                _, J_sel, _ = choose(self.model, self.x, p, grid, J, self.settings, polish=False)
                J = np.concatenate([J, J_sel])
        except NoCandidates:
            return float("inf")
        return -plan_index(J, self.settings.criterion, self.rank, self.settings.weight)


def _swarm(
    fitness: _Fitness,
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


# -- the whole plan ------------------------------------------------------------------
def select_configurations(
    model: SystemModel,
    x: F64,
    spheres_part_mm: Mapping[str, ArrayLike],
    settings: PlanSettings,
    grid: ViewGrid | None = None,
    J_fixed: F64 | None = None,
) -> tuple[list[SpherePlan], F64]:
    """The configurations of each sphere at fixed positions, in order, each choice counting
    the ones before; returns the sphere plans and all their Jacobian blocks."""
    L = len(settings.active)
    J = np.zeros((0, 3, L)) if J_fixed is None else J_fixed
    plans: list[SpherePlan] = []
    for name, p in spheres_part_mm.items():
        sphere, J_sel = _configure_sphere(model, x, name, p, grid or settings.grid, J, settings)
        J = np.concatenate([J, J_sel])
        plans.append(sphere)
    return plans, J


def _configure_sphere(
    model: SystemModel,
    x: F64,
    name: str,
    p_part_mm: ArrayLike,
    grid: ViewGrid,
    J_fixed: F64,
    settings: PlanSettings,
) -> tuple[SpherePlan, F64]:
    """The final configurations of one sphere (chosen with the fixed blocks, refined on the
    model) and their Jacobian blocks at the refined angles."""
    p_arr = np.asarray(p_part_mm, dtype=float).reshape(3)
    cand, J = candidate_blocks(model, x, p_arr, grid, settings, settings.threads)
    if settings.criterion == "I":
        settings = _stage_settings(settings, _reachable_rank(J_fixed, J) if len(J) else 0)
    try:
        chosen, _, n_cand = _choose_from(cand, J, J_fixed, settings, threads=settings.threads)
    except NoCandidates as exc:
        raise NoCandidates(f"sphere {name}: {exc}") from None
    q, ok = refine_on_model(model, x, chosen.q_deg)
    J_sel = model.point_jacobian(x, q, chosen.c_sensor_mm, settings.active)
    sphere = SpherePlan(name, p_arr, q, chosen.c_sensor_mm, n_cand, int(np.sum(~ok)))
    return sphere, J_sel


def revisit(
    model: SystemModel,
    x: F64,
    spheres: list[SpherePlan],
    settings: PlanSettings,
    progress: Progress | None = None,
) -> tuple[list[SpherePlan], F64]:
    """Up to `settings.revisits` passes over the spheres, each choosing a sphere's
    configurations anew with the other spheres' as the fixed ones (a choice is kept unless
    the criterion improves); stops after a pass that changes nothing. Returns the spheres
    and all their blocks."""
    blocks = [model.point_jacobian(x, sp.q_deg, sp.c_sensor_mm, settings.active) for sp in spheres]
    value = _criterion_value(np.concatenate(blocks), settings)
    for n in range(settings.revisits):
        changed = False
        for k, sp in enumerate(spheres):
            fixed = np.concatenate([b for j, b in enumerate(blocks) if j != k])
            new, J_new = _configure_sphere(model, x, sp.name, sp.p_part_mm, settings.grid,
                                           fixed, settings)  # fmt: skip
            trial = _criterion_value(np.concatenate([fixed, J_new]), settings)
            if trial > value * (1.0 + 1e-9):
                spheres, blocks = _replace(spheres, k, new), _replace(blocks, k, J_new)
                value, changed = trial, True
        if progress:
            progress("revisit", n + 1, settings.revisits, value)
        if not changed:
            break
    return spheres, np.concatenate(blocks)


def _criterion_value(J_blocks: F64, settings: PlanSettings) -> float:
    return plan_index(J_blocks, settings.criterion, weight=settings.weight)


def _replace(items: list[Any], k: int, item: Any) -> list[Any]:
    return [*items[:k], item, *items[k + 1 :]]


def refine_on_model(model: SystemModel, x: F64, q_deg: F64) -> tuple[F64, NDArray[np.bool_]]:
    """The closed form solves the nominal joints with x's part->base and hand-eye: refine its
    configurations on the whole model x so that the sensor reaches the pose the closed form
    aimed at (the sphere then appears where planned). Keeps the closed-form angles where the
    refinement does not converge; returns (q_deg, converged)."""
    x_frames = model.nominal_x()
    frames = [INDEX[n] for n in (*BASE_NAMES, *SENSOR_NAMES)]
    x_frames[frames] = x[frames]
    target = model.fk(x_frames, q_deg)
    r = refine(model, x, target, q_deg)
    q = np.where(r.converged[:, None], r.q_deg, q_deg)
    return q, r.converged


def plan(
    model: SystemModel,
    x: F64,
    spheres_part_mm: Mapping[str, ArrayLike],
    settings: PlanSettings | None = None,
    region: FeasibleRegion | None = None,
    *,
    progress: Progress | None = None,
    map_fn: MapFn | None = None,
) -> Plan:
    """Plan sphere positions (heights kept from spheres_part_mm, which also gives the start)
    and their configurations on the pre-calibrated parameters x."""
    s = settings or PlanSettings()
    region = region or FeasibleRegion()
    mapper: MapFn = map_fn or map
    names = list(spheres_part_mm)
    T_base_part = inverse(model.T_part_base(x))
    start_base = np.array(
        [apply(T_base_part, np.asarray(spheres_part_mm[k], float)) for k in names]
    )
    z_base = tuple(float(z) for z in start_base[:, 2])
    L = len(s.active)
    seconds: dict[str, float] = {}
    history: dict[str, F64] = {}
    t0 = time.perf_counter()
    xy = start_base[:, :2].copy()
    if s.placement != "fixed":
        region.sample(np.random.default_rng(0), 1)  # EmptyRegion early
    J_fixed = np.zeros((0, 3, L))
    spheres: list[SpherePlan] = []
    if s.placement == "sequential":
        # each sphere's final configurations are chosen right after its swarm (they are the
        # fixed ones of the next swarm), once: the final stage has nothing left to choose
        for k, name in enumerate(names):
            t = time.perf_counter()
            fit = _fitness(model, x, (z_base[k],), xy[:k], J_fixed, s, region, xy[k])
            best, history[name] = _swarm(fit, region, 1, xy[k], f"place {name}", progress, mapper)
            xy[k] = best[0]
            p = _part_from_base(model, x, xy[k], z_base[k])
            sphere, J_sel = _configure_sphere(model, x, name, p, s.grid, J_fixed, s)
            spheres.append(sphere)
            J_fixed = np.concatenate([J_fixed, J_sel])
            seconds[f"place {name}"] = time.perf_counter() - t
    elif s.placement == "joint":
        t = time.perf_counter()
        fit = _fitness(model, x, z_base, np.zeros((0, 2)), J_fixed, s, region, xy)
        xy, history["joint"] = _swarm(fit, region, len(names), xy, "place all", progress, mapper)
        seconds["place all"] = time.perf_counter() - t
    t = time.perf_counter()
    positions = {n: _part_from_base(model, x, xy[k], z_base[k]) for k, n in enumerate(names)}
    if progress:
        progress("configurations", 0, 1, float("nan"))
    if not spheres:
        spheres, J_fixed = select_configurations(model, x, positions, s)
    if s.revisits:
        spheres, J_fixed = revisit(model, x, spheres, s, progress)
    J_all = J_fixed
    obs = observability(J_all.reshape(-1, L), J_all.shape[0])
    if progress:
        progress("configurations", 1, 1, plan_index(J_all, s.criterion, weight=s.weight))
    seconds["configurations"] = time.perf_counter() - t
    rq, rc, r_obs = random_plan(model, x, positions, s)
    seconds["total"] = time.perf_counter() - t0
    return Plan(tuple(spheres), obs, r_obs, rq, rc, s, history, seconds)


def _fitness(
    model: SystemModel,
    x: F64,
    z_base: tuple[float, ...],
    placed_xy: F64,
    J_fixed: F64,
    s: PlanSettings,
    region: FeasibleRegion,
    xy_start: F64,
) -> _Fitness:
    """The fitness of a stage, with the rank reachable from the start position."""
    J_pool = [J_fixed]
    for (px, py), z in zip(np.reshape(xy_start, (-1, 2)), z_base, strict=True):
        _, J = candidate_blocks(
            model, x, _part_from_base(model, x, np.array([px, py]), z), s.search_grid, s
        )
        J_pool.append(J)
    pool = np.concatenate(J_pool)
    rank = _reachable_rank(np.zeros((0, 3, pool.shape[2])), pool) if len(pool) else len(s.active)
    s = _stage_settings(s, rank)
    return _Fitness(
        model, x, z_base, np.asarray(placed_xy).reshape(-1, 2), J_fixed, s, region, rank
    )


def _stage_settings(s: PlanSettings, rank: int) -> PlanSettings:
    """The settings of a stage that reaches `rank` directions: a partial plan (rank < L) is
    chosen by O1 when the criterion is "I", whose workspace error depends on the directions
    that only the later spheres will determine (I refines full plans: revisits, last sphere)."""
    if s.criterion == "I" and rank < len(s.active):
        return replace(s, criterion="O1")
    return s


def random_plan(
    model: SystemModel,
    x: F64,
    spheres_part_mm: Mapping[str, ArrayLike],
    settings: PlanSettings,
) -> tuple[dict[str, F64], dict[str, F64], Observability]:
    """The baseline at the same positions: n random configurations per sphere."""
    rng = np.random.default_rng([settings.seed, 7])
    qs: dict[str, F64] = {}
    cs: dict[str, F64] = {}
    blocks = []
    for name, p in spheres_part_mm.items():
        v = random_configurations(model, x, p, settings.n_per_sphere, rng)
        qs[name], cs[name] = v.q_deg, v.c_planned_mm
        blocks.append(model.point_jacobian(x, v.q_deg, v.c_planned_mm, settings.active))
    J = np.concatenate(blocks)
    return qs, cs, observability(J.reshape(-1, J.shape[2]), J.shape[0])
