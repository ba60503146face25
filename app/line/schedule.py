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
from app.motion import motion_time_s

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Slot:
    """Position `index` of the schedule: measure sphere `target` from `q_deg` (controller
    angles [deg], shape (6,))."""

    index: int
    target: str
    q_deg: F64


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

    def views(self, spheres_part_mm: Mapping[str, ArrayLike]) -> tuple[F64, F64]:
        """Every slot's configuration (n, 6) [deg] and its sphere's centre in the part frame
        (n, 3) [mm], in cycle order."""
        q = np.array([s.q_deg for s in self.slots], dtype=np.float64).reshape(-1, 6)
        p = np.array([spheres_part_mm[s.target] for s in self.slots], dtype=np.float64)
        return q, p.reshape(-1, 3)

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
