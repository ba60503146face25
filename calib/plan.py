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

The pieces: calib.plan_settings (the region, the settings, the result), calib.configurations
(one sphere's configurations, revisits), calib.placement (the swarm); this module runs them in
order and adds the random baseline at the same positions.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from calib.candidates import random_configurations
from calib.configurations import configure_sphere, plan_index, revisit, select_configurations
from calib.model import SystemModel
from calib.observability import Observability, observability
from calib.placement import fitness, part_from_base, swarm
from calib.plan_settings import F64, FeasibleRegion, MapFn, Plan, PlanSettings, Progress, SpherePlan
from calib.transforms import apply, inverse


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
            fit = fitness(model, x, (z_base[k],), xy[:k], J_fixed, s, region, xy[k])
            best, history[name] = swarm(fit, region, 1, xy[k], f"place {name}", progress, mapper)
            xy[k] = best[0]
            p = part_from_base(model, x, xy[k], z_base[k])
            sphere, J_sel = configure_sphere(model, x, name, p, s.grid, J_fixed, s)
            spheres.append(sphere)
            J_fixed = np.concatenate([J_fixed, J_sel])
            seconds[f"place {name}"] = time.perf_counter() - t
    elif s.placement == "joint":
        t = time.perf_counter()
        fit = fitness(model, x, z_base, np.zeros((0, 2)), J_fixed, s, region, xy)
        xy, history["joint"] = swarm(fit, region, len(names), xy, "place all", progress, mapper)
        seconds["place all"] = time.perf_counter() - t
    t = time.perf_counter()
    positions = {n: part_from_base(model, x, xy[k], z_base[k]) for k, n in enumerate(names)}
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
