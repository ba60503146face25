"""The configurations of each sphere (paper section 4.3): the candidate views of a sphere on an
orientation grid (calib.candidates) with their identification-Jacobian blocks on the
pre-calibrated model, DETMAX (calib.detmax) choosing n of them together with the
configurations already chosen for the other spheres, revisits of a whole plan, and the
refinement of the chosen closed-form angles on the whole model.

Partial plans: while fewer spheres are placed the Jacobian cannot reach rank L (one sphere
gives at most 27 of the 30 directions, two 29), so the index takes the r largest singular
values of the column-scaled Jacobian, r the rank that the fixed configurations and the whole
candidate pool reach together; with four spheres r = L and the index is the usual one.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import detmax
from calib.candidates import Candidates, ViewGrid, sphere_candidates
from calib.errors import NoCandidates
from calib.ik_refine import refine
from calib.ioptimal import check_weight, i_index
from calib.model import BASE_NAMES, INDEX, SENSOR_NAMES, SystemModel
from calib.observability import column_scaled, index_from_singular_values
from calib.plan_settings import PlanSettings, Progress, SpherePlan

F64 = NDArray[np.float64]


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
    return choose_from(cand, J, J_fixed, settings, polish=polish, threads=threads)


def choose_from(
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


def candidate_blocks_of_many(
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


def reachable_rank(J_fixed: F64, J_pool: F64) -> int:
    blocks = np.concatenate([J_fixed, J_pool])
    Js, _ = column_scaled(blocks.reshape(-1, blocks.shape[2]))
    lam = np.linalg.eigvalsh(Js.T @ Js)
    return max(1, int(np.sum(lam > 1e-12 * lam[-1])))


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
        sphere, J_sel = configure_sphere(model, x, name, p, grid or settings.grid, J, settings)
        J = np.concatenate([J, J_sel])
        plans.append(sphere)
    return plans, J


def configure_sphere(
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
        settings = stage_settings(settings, reachable_rank(J_fixed, J) if len(J) else 0)
    try:
        chosen, _, n_cand = choose_from(cand, J, J_fixed, settings, threads=settings.threads)
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
            new, J_new = configure_sphere(model, x, sp.name, sp.p_part_mm, settings.grid,
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


def stage_settings(s: PlanSettings, rank: int) -> PlanSettings:
    """The settings of a stage that reaches `rank` directions: a partial plan (rank < L) is
    chosen by O1 when the criterion is "I", whose workspace error depends on the directions
    that only the later spheres will determine (I refines full plans: revisits, last sphere)."""
    if s.criterion == "I" and rank < len(s.active):
        return replace(s, criterion="O1")
    return s
