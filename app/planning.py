"""Wiring of the planner: settings from the cell configuration, a process pool for the swarm,
a progress display, and the plan file (JSON, format `rvis-plan`).

Plan file:
    {"format": "rvis-plan", "format_version": 1, "cell": <source>, "settings": {...},
     "spheres": [{"name", "position_part_mm", "position_base_mm", "n_candidates", "n_unrefined",
                  "configurations": [{"q_deg": [6], "c_sensor_mm": [3]}, ...]}, ...],
     "observability": {O1..O5, rank, condition}, "random_plan": {O1..O5, rank, condition,
     "configurations": {name: [{"q_deg", "c_sensor_mm"}, ...]}}, "seconds": {...}}
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.errors import InputError
from app.formats.files import read_json
from app.workspace import weight_for
from calib.candidates import FOV_CENTRE_MM, FOV_SPREAD_MM, Clearance, ViewGrid
from calib.detmax import CRITERIA, METHODS
from calib.errors import PlanningError
from calib.model import SystemModel
from calib.observability import Observability
from calib.plan import plan
from calib.plan_settings import PLACEMENTS, FeasibleRegion, MapFn, Plan, PlanSettings
from calib.pso import SwarmSettings
from calib.transforms import apply, inverse

F64 = NDArray[np.float64]
FORMAT = "rvis-plan"
FORMAT_VERSION = 1


PLAN_OPTIONS = (
    "placement",
    "criterion",
    "method",
    "iterations",
    "patience",
    "swarm_size",
    "grid_step_deg",
    "search_step_deg",
    "workers",
    "revisits",
)


def add_plan_options(p: argparse.ArgumentParser) -> None:
    """The command-line options that override the cell's [planning] table."""
    p.add_argument("--placement", choices=PLACEMENTS, help="sequential (paper), joint, fixed")
    p.add_argument(
        "--criterion",
        help=f"selection criterion, one of {', '.join(CRITERIA)} (I: workspace accuracy)",
    )
    p.add_argument("--method", choices=METHODS, help="selection method (default detmax)")
    p.add_argument("--iterations", type=int, help="PSO iterations (default 30)")
    p.add_argument(
        "--patience",
        type=int,
        help="stop a swarm after N iterations without an improvement of its best by more than "
        "[planning] stall_tolerance (0: run every iteration)",
    )
    p.add_argument("--swarm", type=int, dest="swarm_size", help="PSO swarm size (default 50)")
    p.add_argument("--grid-step", type=float, dest="grid_step_deg", help="final grid [deg]")
    p.add_argument("--search-step", type=float, dest="search_step_deg", help="PSO grid [deg]")
    p.add_argument("--workers", type=int, help="processes for the swarm (default 2)")
    p.add_argument(
        "--revisits",
        type=int,
        help="passes re-choosing each sphere's configurations given the others (default 0)",
    )


def plan_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The planning options given on the command line, checked (InputError naming the option)."""
    out = {k: getattr(args, k) for k in PLAN_OPTIONS if getattr(args, k, None) is not None}
    if "criterion" in out and out["criterion"] not in CRITERIA:
        raise InputError(
            f"unknown criterion '{out['criterion']}' (choose from {', '.join(CRITERIA)})",
            field="--criterion",
        )
    for key, lo in (
        ("iterations", 1),
        ("patience", 0),
        ("swarm_size", 2),
        ("workers", 1),
        ("revisits", 0),
    ):
        if key in out and out[key] < lo:
            option = "--swarm" if key == "swarm_size" else f"--{key}"
            raise InputError(f"must be >= {lo}, got {out[key]}", field=option)
    for key in ("grid_step_deg", "search_step_deg"):
        if key in out and not 0.0 < out[key] <= 90.0:
            option = "--" + key.removesuffix("_deg").replace("_", "-")
            raise InputError(f"must lie in (0, 90] deg, got {out[key]}", field=option)
    return out


def plan_settings(cfg: CellConfig, **overrides: Any) -> tuple[PlanSettings, FeasibleRegion]:
    """PlanSettings and the feasible region from the cell's [planning] section; `overrides`
    replace [planning] keys (None values are ignored)."""
    p = {**cfg.planning, **{k: v for k, v in overrides.items() if v is not None}}
    offsets = FOV_SPREAD_MM if p["fov_offsets"] == "spread" else FOV_CENTRE_MM
    grid = ViewGrid(float(p["grid_step_deg"]), float(p["max_tilt_deg"]), offsets_mm=offsets)
    settings = PlanSettings(
        n_per_sphere=int(cfg.calibration["configs_per_sphere"]),
        criterion=str(p["criterion"]),
        method=str(p["method"]),
        placement=str(p["placement"]),
        grid=grid,
        search_grid=replace(grid, step_deg=max(float(p["search_step_deg"]), grid.step_deg)),
        swarm=SwarmSettings(
            n_particles=int(p["swarm_size"]),
            n_iterations=int(p["iterations"]),
            patience=int(p["patience"]),
            tolerance=float(p["stall_tolerance"]),
        ),
        clearance=Clearance(
            float(p["clearance_above_sphere_mm"]),
            float(p["floor_z_mm"]),
            float(p["clearance_above_floor_mm"]),
        ),
        min_separation_mm=float(p["min_separation_mm"]),
        seed=int(p["seed"]),
        threads=int(p["workers"]),
        revisits=int(p["revisits"]),
    )
    region = FeasibleRegion(
        plate_mm=cfg.base_plate_mm,
        box_mm=tuple(p["workspace_mm"]),
        r_max_mm=float(p["reach_mm"]),
        plate_margin_mm=float(p["plate_margin_mm"]),
    )
    return settings, region


def with_weight(
    settings: PlanSettings, cfg: CellConfig, model: SystemModel, x: F64
) -> PlanSettings:
    """The settings with the workspace weight on parameters x when the criterion is "I"
    (app.workspace); unchanged otherwise."""
    if settings.criterion != "I":
        return settings
    return replace(settings, weight=weight_for(cfg, model, x, settings.active, settings.seed))


@contextmanager
def particle_map(workers: int) -> Iterator[MapFn | None]:
    """A map over blocks of particles on `workers` processes (None: in this process)."""
    if workers <= 1:
        yield None
        return
    ctx = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:

        def mapper(f: Callable[[F64], F64], blocks: Iterable[F64]) -> Iterable[F64]:
            # one block of particles per task (calib.placement.PARTICLE_BLOCK): particles differ in
            # cost (an infeasible one returns at once), and the swarm waits for the slowest
            return pool.map(f, list(blocks), chunksize=1)

        yield mapper


class ProgressLine:
    """Progress of the planner on one terminal line (or a line per stage when not a tty)."""

    def __init__(self, stream: TextIO | None = None, criterion: str = "O1") -> None:
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.criterion = criterion

    def __call__(self, stage: str, step: int, steps: int, best: float) -> None:
        value = "" if np.isnan(best) else f"  best {self.criterion} {best:.4f}"
        text = f"  {stage:<16} {step:>3}/{steps}{value}"
        if self.tty:
            end = "\n" if step == steps else ""
            self.stream.write("\r" + text + end)
        elif step == steps:
            self.stream.write(text + "\n")
        self.stream.flush()


def run_plan(
    cfg: CellConfig,
    model: SystemModel,
    x: F64,
    spheres_part_mm: Mapping[str, F64] | None = None,
    *,
    progress: Callable[[str, int, int, float], None] | None = None,
    **overrides: Any,
) -> Plan:
    """Plan on parameters x for the parameters `model` identifies by default (the paper's 30
    for the rigid model; with the arm compliance for the compliant one); planning errors
    become input errors (exit code 2)."""
    settings, region = plan_settings(cfg, **overrides)
    settings = replace(settings, active=tuple(model.default_active()))
    settings = with_weight(settings, cfg, model, x)
    workers = int(overrides.get("workers") or cfg.planning["workers"])
    spheres = spheres_part_mm or cfg.spheres_part_mm
    try:
        with particle_map(workers) as mapper:
            return plan(model, x, spheres, settings, region, progress=progress, map_fn=mapper)
    except (PlanningError, ValueError) as exc:
        raise InputError(str(exc), file=cfg.source, field="planning") from exc


def _indices(obs: Observability) -> dict[str, float | int]:
    return {**obs.indices, "rank": obs.rank, "condition": obs.condition}


def plan_to_json(cfg: CellConfig, model: SystemModel, x: F64, result: Plan) -> dict[str, Any]:
    s = result.settings
    T_base_part = inverse(model.T_part_base(x))
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "cell": cfg.source,
        "settings": {
            "configs_per_sphere": s.n_per_sphere,
            "criterion": s.criterion,
            "method": s.method,
            "placement": s.placement,
            "grid_step_deg": s.grid.step_deg,
            "search_step_deg": s.search_grid.step_deg,
            "max_tilt_deg": s.grid.max_tilt_deg,
            "swarm_size": s.swarm.n_particles,
            "iterations": s.swarm.n_iterations,
            "patience": s.swarm.patience,
            "stall_tolerance": s.swarm.tolerance,
            "seed": s.seed,
            "revisits": s.revisits,
            "parameters": list(s.active),
        },
        "spheres": [
            {
                "name": sp.name,
                "position_part_mm": sp.p_part_mm.tolist(),
                "position_base_mm": apply(T_base_part, sp.p_part_mm).tolist(),
                "n_candidates": sp.n_candidates,
                "n_unrefined": sp.n_unrefined,
                "configurations": [
                    {"q_deg": q.tolist(), "c_sensor_mm": c.tolist()}
                    for q, c in zip(sp.q_deg, sp.c_sensor_mm, strict=True)
                ],
            }
            for sp in result.spheres
        ],
        "observability": _indices(result.observability),
        "random_plan": {
            **_indices(result.random_observability),
            "configurations": {
                k: [
                    {"q_deg": q.tolist(), "c_sensor_mm": c.tolist()}
                    for q, c in zip(v, result.random_c_sensor_mm[k], strict=True)
                ]
                for k, v in result.random_q_deg.items()
            },
        },
        "fitness_history": {k: v.tolist() for k, v in result.fitness_history.items()},
        "seconds": result.seconds,
    }


def read_plan(path: str | Path) -> tuple[dict[str, F64], dict[str, F64], dict[str, F64]]:
    """(positions part frame, q_deg per sphere (n, 6), c_sensor_mm per sphere (n, 3)) from a
    plan file; InputError naming the field when malformed."""
    data = read_json(path)
    if data.get("format") != FORMAT:
        raise InputError(
            f"not an rvis plan (format {data.get('format')!r})", file=path, field="format"
        )
    positions: dict[str, F64] = {}
    qs: dict[str, F64] = {}
    cs: dict[str, F64] = {}
    spheres = data.get("spheres")
    if not isinstance(spheres, list) or not spheres:
        raise InputError("expected a list of spheres", file=path, field="spheres")
    for k, sp in enumerate(spheres):
        where = f"spheres[{k}]"
        try:
            name = str(sp["name"])
            positions[name] = _array(sp["position_part_mm"], (3,))
            confs = sp["configurations"]
            qs[name] = np.array([_array(c["q_deg"], (6,)) for c in confs]).reshape(-1, 6)
            cs[name] = np.array([_array(c["c_sensor_mm"], (3,)) for c in confs]).reshape(-1, 3)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"malformed sphere entry ({exc})", file=path, field=where) from None
    return positions, qs, cs


def _array(value: Any, shape: tuple[int, ...]) -> F64:
    a = np.asarray(value, dtype=float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ValueError(f"expected {shape[0]} finite numbers")
    return a
