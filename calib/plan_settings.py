"""The planning's vocabulary (calib.plan): where a sphere may stand (`FeasibleRegion`), the
settings of a plan (`PlanSettings`), and its result (`SpherePlan`, `Plan`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import detmax
from calib.candidates import Clearance, ViewGrid
from calib.errors import EmptyRegion
from calib.model import PAPER_30
from calib.observability import Observability
from calib.pso import SwarmSettings

F64 = NDArray[np.float64]
PLACEMENTS = ("sequential", "joint", "fixed")
#: Progress callback: (stage, step, steps, best fitness so far).
Progress = Callable[[str, int, int, float], None]
#: A map over blocks of particles (k, d) -> fitness values (k,), e.g. a process pool's `map`
#: (default: the builtin).
MapFn = Callable[[Callable[[F64], F64], Iterable[F64]], Iterable[F64]]


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
