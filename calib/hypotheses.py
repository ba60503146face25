"""What can jump in the cell and what a jump test found: the hypotheses (the groups of the
model that a knock moves at once, calib.attribution's, and each sphere alone; J2's encoder zero
beyond a knock) and a hypothesis's fit at its best onset (calib.cellstate's test).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from calib.attribution import NONE, SEVERAL, maintenance_groups, step_groups
from calib.model import SystemModel, unit_of

F64 = NDArray[np.float64]
SPHERE = "sphere:"  # a hypothesis's name prefix: one sphere moved alone


@dataclass(frozen=True)
class Hypothesis:
    """What can jump at once: `params` of the model (a group), or one sphere (`target`)."""

    name: str
    label: str
    params: tuple[str, ...] = ()
    target: str | None = None


def hypotheses(model: SystemModel, targets: Sequence[str]) -> tuple[Hypothesis, ...]:
    """The groups a knock moves (calib.attribution.step_groups, without "nothing" and the
    full set) and each sphere alone."""
    groups = [g for g in step_groups(model) if g.name not in (NONE, SEVERAL)]
    return (
        *(Hypothesis(g.name, g.label, g.params) for g in groups),
        *(Hypothesis(f"{SPHERE}{t}", f"sphere {t} alone", target=t) for t in sorted(targets)),
    )


def beyond_hypotheses(model: SystemModel) -> tuple[Hypothesis, ...]:
    """The groups only a change beyond a knock moves (calib.attribution.maintenance_groups
    less the knocks': J2's encoder zero with J3 coupled), tested on request (`fit`): among the
    knocks' its spare parameter would let noise pick it over J2's zero alone."""
    knocks = {g.name for g in step_groups(model)}
    return tuple(
        Hypothesis(g.name, g.label, g.params)
        for g in maintenance_groups(model)
        if g.name not in knocks
    )


@dataclass(frozen=True)
class JumpFit:
    """A hypothesis's best onset: `onset` (index into the window), `onset_ref` (the caller's
    id of that measurement), the statistic `llr` (2 log LR) with `dof`, its `p_value`, the
    Schwarz `score`, the jump `theta` and its covariance `cov` (the group's units: mm, rad)."""

    hypothesis: Hypothesis
    onset: int
    onset_ref: int
    llr: float
    dof: int
    p_value: float
    score: float
    theta: F64
    cov: F64

    @property
    def std(self) -> F64:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def size_text(self) -> str:
        """The jump in its own terms: translation and rotation of a 6-DoF group, a joint
        zero's offset, a sphere's move."""
        h, th = self.hypothesis, self.theta
        if h.target is not None:
            return f"{float(np.linalg.norm(th)):.3f} mm"
        mm = [k for k, n in enumerate(h.params) if unit_of(n) == "mm"]
        rad = [k for k, n in enumerate(h.params) if unit_of(n) == "rad"]
        if mm:
            t_mm = float(np.linalg.norm(th[mm]))
            r_deg = float(np.degrees(np.linalg.norm(th[rad])))
            return f"{t_mm:.3f} mm / {r_deg:.4f} deg"
        return ", ".join(f"{n} {np.degrees(v):+.4f} deg" for n, v in zip(h.params, th, strict=True))


@dataclass(frozen=True)
class Verdict:
    """After a measurement: `detected` (a jump at the stated false-alarm rate), `isolated`:
    the hypothesis's name, SEVERAL (none decisive or none explains) or "" (nothing detected);
    `best` and `runner_up` fits; `nis` the window's normalised innovation squared per degree
    of freedom under no jump (about 1 for a consistent model); `threshold_p`."""

    detected: bool
    isolated: str
    best: JumpFit | None
    runner_up: JumpFit | None
    nis: float
    threshold_p: float
    fits: tuple[JumpFit, ...] = ()
