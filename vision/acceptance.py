"""The sensor's acceptance test in the manner of VDI/VDE 2634 Part 2 (and ISO 10360-8).

A calibrated sphere is measured at several positions across the measuring volume (the guideline
asks for about 7-10: near, far, left, right, top, bottom, centre, corners). From each sweep:

- PF, probing error form: the range of the radial distances of all the sweep's points from the
  least-squares sphere with free radius, at most 0.3 % of the points left out as outliers
  (vision.spherefit.form_error, every fit's `FitQuality.form_mm`; the centre is the robust fit's,
  another fact); a range, never negative;
- PS, probing error size: the free-fit diameter minus the certified diameter.

Between positions, SD, sphere-spacing error: the distance between two measured centres minus the
reference distance. rvis's artefact is one sphere that the robot moves through the measuring
volume (the sensor keeps its orientation, so its frames at two positions are parallel): the
reference is the sphere's displacement in the sensor frame that the robot's motion implies,
from the poses `T_ref_sensor` (the calibrated kinematic model's forward kinematics, in any fixed
frame). Over the volume's few centimetres the robot's relative error is a few micrometres on a
calibrated model, far below a sensor's scale error (0.1 % of 25 mm is 25 um); its
non-repeatable error is not (tens of micrometres per stop), so the caller states the robot's
share of SD (`AcceptanceLimits.sd_robot_mm`, ISO 14253-1: the limit widened by the reference's
uncertainty).

Each figure's largest magnitude is compared with its limit: PF the largest of the positions'
ranges, PS the largest |PS| of the positions, SD the largest |SD| of the pairs (36 for 9
positions); `Acceptance.worst` names the position or pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class AcceptanceLimits:
    """Largest magnitudes allowed [mm] for PF, PS and SD; sd_robot_mm: the expanded
    uncertainty of SD's reference (the robot's motion), added to sd_mm."""

    pf_mm: float
    ps_mm: float
    sd_mm: float
    sd_robot_mm: float = 0.0

    def of(self, figure: str) -> float:
        """The largest magnitude allowed [mm] for "PF", "PS" or "SD"."""
        return {"PF": self.pf_mm, "PS": self.ps_mm, "SD": self.sd_mm + self.sd_robot_mm}[figure]


@dataclass(frozen=True, eq=False)
class Acceptance:
    """pf_mm, ps_mm shape=(n,) per position; sd_mm shape=(m,) per pair of positions `pairs`
    (m, 2); the figures (largest magnitudes), the limits, whether each passed and a message."""

    pf_mm: F64
    ps_mm: F64
    sd_mm: F64
    pairs: NDArray[np.intp]
    limits: AcceptanceLimits

    def of(self, figure: str) -> F64:
        """PF or PS per position, SD per pair [mm]."""
        return {"PF": self.pf_mm, "PS": self.ps_mm, "SD": self.sd_mm}[figure]

    def worst(self, figure: str) -> int:
        """The position ("PF", "PS") or the pair ("SD", a row of `pairs`) of the largest
        magnitude, by its index (-1: none measured)."""
        a = self.of(figure)
        return int(np.argmax(np.abs(a))) if a.size else -1

    @property
    def figures(self) -> dict[str, float]:
        """Each figure's value at its worst position or pair [mm] (signed; nan: none)."""
        return {
            k: float(self.of(k)[i]) if (i := self.worst(k)) >= 0 else float("nan")
            for k in ("PF", "PS", "SD")
        }

    @property
    def passed_each(self) -> dict[str, bool]:
        return {
            k: bool(np.isfinite(v) and abs(v) <= self.limits.of(k)) for k, v in self.figures.items()
        }

    @property
    def passed(self) -> bool:
        return all(self.passed_each.values())

    @property
    def message(self) -> str:
        """ "PF 98.7 um, the largest of 9 positions' ranges, within 150.0 um; PS ...": each
        figure, what it is the largest of, and its limit (PF a range: no sign)."""
        f, ok, lim = self.figures, self.passed_each, self.limits
        n, m = len(self.pf_mm), len(self.sd_mm)
        what = {
            "PF": f"PF {1000 * f['PF']:.1f} um, the largest of {n} positions' ranges",
            "PS": f"PS {1000 * f['PS']:+.1f} um, the largest |PS| of {n} positions",
            "SD": f"SD {1000 * f['SD']:+.1f} um, the largest |SD| of {m} pairs",
        }
        limit = {
            "PF": f"{1000 * lim.pf_mm:.1f} um",
            "PS": f"+-{1000 * lim.ps_mm:.1f} um",
            "SD": f"+-{1000 * lim.of('SD'):.1f} um"
            + (
                f" ({1000 * lim.sd_mm:.1f} + the robot's share {1000 * lim.sd_robot_mm:.1f})"
                if lim.sd_robot_mm
                else ""
            ),
        }
        return "; ".join(
            f"{what[k]}, {'within' if ok[k] else 'beyond'} {limit[k]}" for k in ("PF", "PS", "SD")
        )


def spacing_errors(c_sensor_mm: F64, T_ref_sensor: F64) -> tuple[NDArray[np.intp], F64]:
    """SD per pair of positions (module docstring).

    c_sensor_mm: shape=(n, 3) the sphere's centre measured at each position, in that position's
    sensor frame [mm]; T_ref_sensor: shape=(n, 4, 4) the sensor poses in a fixed frame (the
    kinematic model's). Returns the pairs (m, 2) and SD (m,) [mm]: |c_a - c_b| minus the
    distance the poses imply for the sphere at its consensus position (the mean of the mapped
    centres)."""
    c = np.asarray(c_sensor_mm, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(T_ref_sensor, dtype=np.float64).reshape(-1, 4, 4)
    if len(c) != len(T):
        raise ValueError(f"{len(c)} centres but {len(T)} poses")
    p = np.mean(np.einsum("nij,nj->ni", T[:, :3, :3], c) + T[:, :3, 3], axis=0)
    c_ref = np.einsum("nji,nj->ni", T[:, :3, :3], p - T[:, :3, 3])
    a, b = np.triu_indices(len(c), k=1)
    measured = np.linalg.norm(c[a] - c[b], axis=1)
    reference = np.linalg.norm(c_ref[a] - c_ref[b], axis=1)
    return np.column_stack([a, b]).astype(np.intp), measured - reference


def probing_size_mm(radius_free_mm: ArrayLike, certified_radius_mm: ArrayLike) -> F64:
    """PS [mm]: the free fit's diameter minus the certified one, 2 (r_free - r_certified); the
    acceptance's and the in-line sensor watch's (app/line/sensor_watch.py) one formula."""
    ps: F64 = 2.0 * (
        np.asarray(radius_free_mm, dtype=np.float64)
        - np.asarray(certified_radius_mm, dtype=np.float64)
    )
    return ps


def acceptance(
    form_mm: F64,
    radius_free_mm: F64,
    certified_radius_mm: float,
    c_sensor_mm: F64,
    T_ref_sensor: F64,
    limits: AcceptanceLimits,
) -> Acceptance:
    """PF, PS and SD of a sphere measured at n positions: its fits' form ranges (PF, n,) and
    free radii (n,) [mm], the certified radius, the centres (n, 3) and sensor poses
    (n, 4, 4)."""
    pairs, sd = spacing_errors(c_sensor_mm, T_ref_sensor)
    ps = probing_size_mm(radius_free_mm, certified_radius_mm)
    return Acceptance(np.asarray(form_mm, dtype=np.float64), ps, sd, pairs, limits)
