"""A fitted feature's characteristic values, each with its task-specific U95 and its decision
per ISO 14253-1.

The U95 of a value along a direction e of the part frame (a position X, Y, Z: the axis; a
surface point's N: the nominal normal) is k sqrt(max(sigma_cell^2, e' C_cal e) + e' C_fit e), k
the two-sided 95 % factor of one coordinate (1.96):
- sigma_cell: the cell's statement for a point measured now (a U95 of the 3-D error's norm, the
  in-line check standard's or the commissioning's workspace validation's), per coordinate:
  U95 / 2.80 (calib.uncertainty.norm_quantile). It is measured on points whose truth is known,
  so it holds every error a point measured now has: the parameters' at the point, the robot's
  repeatability at the stop, the sphere's sensing, what the model leaves out;
- C_cal (3, 3): the identification's covariance propagated to the feature's centre at its view
  (J P J', as `rvis.Calibration.u95_mm` propagates it): the parameters' part alone, but at this
  pose. Added to sigma_cell it would count the parameters twice; the larger of the two stands,
  so a pose where the parameters are less certain than on average is never understated;
- C_fit (3, 3): the feature fit's own covariance (vision.features): the feature's sensing,
  which the sphere's does not contain.
A size (D, W, L) is a distance within one view: the pose's error moves both edges alike, so
its U95 is k sqrt(sd_fit^2 + 2 u_edge^2): the fit's own sd holds the edge points' random
placement within a stripe sample; u_edge is the type-B uncertainty of what stays systematic on
every edge point of one side (`EDGE_U_MM`).

Decision (ISO 14253-1): conformance proven when the value lies inside the tolerance shrunk by
U on each side, nonconformance proven when it lies outside the tolerance widened by U, else
undecided. A feature that was not measured gives "not measured" with its reason, never a number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.inspect.plan import Characteristic, Feature
from calib.uncertainty import norm_quantile
from vision.features import FeatureFit

F64 = NDArray[np.float64]
#: the one-coordinate two-sided 95 % coverage factor
K95 = 1.959964
#: type-B standard uncertainty [mm] of what stays systematic in the edge points' placement: an
#: edge is put half a sample step past the last point on the sheet (vision.sheet), the step
#: measured in the sheet's plane; what that leaves is bounded by a tenth of the step (0.036 mm
#: at the working distance), as a uniform distribution's
EDGE_U_MM = 0.0036 / math.sqrt(3.0)  # 0.002 mm
DECISIONS = ("conforming", "nonconforming", "undecided", "not measured")


@dataclass(frozen=True)
class Value:
    """One characteristic's value: measured_mm, deviation_mm (measured - nominal) and u95_mm
    are None when not measured (`reason` says why); decision one of DECISIONS."""

    characteristic: Characteristic
    measured_mm: float | None
    deviation_mm: float | None
    u95_mm: float | None
    decision: str
    reason: str = ""

    def as_dict(self) -> dict[str, object]:
        c = self.characteristic
        lower, upper = c.limits_mm
        return {
            "feature": c.feature,
            "characteristic": c.name,
            "kind": c.kind,
            "nominal_mm": c.nominal_mm,
            "measured_mm": self.measured_mm,
            "deviation_mm": self.deviation_mm,
            "lower_mm": lower,
            "upper_mm": upper,
            "u95_mm": self.u95_mm,
            "decision": self.decision,
            "reason": self.reason,
        }


def decide(deviation_mm: float, tol_mm: tuple[float, float], u95_mm: float) -> str:
    """ISO 14253-1 (module docstring)."""
    lo, hi = tol_mm
    if lo + u95_mm <= deviation_mm <= hi - u95_mm:
        return "conforming"
    if deviation_mm < lo - u95_mm or deviation_mm > hi + u95_mm:
        return "nonconforming"
    return "undecided"


def cell_sigma_mm(statement_u95_mm: float) -> float:
    """The per-coordinate standard uncertainty [mm] of the cell's statement (a 3-D norm's U95)."""
    return statement_u95_mm / norm_quantile()


def feature_values(
    feature: Feature,
    fit: FeatureFit,
    cov_cal_mm2: F64,
    statement_u95_mm: float,
    stops: int = 1,
    cov_repeat_mm2: F64 | None = None,
) -> list[Value]:
    """The values of `feature` from its fit in the part frame; cov_cal_mm2 (3, 3): the
    calibration's covariance at the feature's centre; statement_u95_mm: the cell's (one
    stop's). A fit averaged over `stops` stops (app.inspect.measure.mean_fit): the robot's
    repeatability at the view, cov_repeat_mm2 (3, 3), is one stop's in the statement and
    1/stops of it in the mean: the statement less the difference (never below nothing)."""
    sigma2 = cell_sigma_mm(statement_u95_mm) ** 2
    out = []
    sizes = iter(zip(fit.size_mm, fit.sd_size_mm, strict=True))
    for c in feature.characteristics():
        if c.kind == "size":
            size, sd = next(sizes)
            measured = size
            u95 = K95 * math.sqrt(sd**2 + 2.0 * EDGE_U_MM**2)
        else:
            if c.name == "N":
                e = feature.normal
                measured = fit.deviation_mm
            else:
                e = np.eye(3)["XYZ".index(c.name)]
                measured = float(fit.centre_mm["XYZ".index(c.name)])
            cell2 = sigma2
            if stops > 1 and cov_repeat_mm2 is not None:
                cell2 -= (1.0 - 1.0 / stops) * min(float(e @ cov_repeat_mm2 @ e), sigma2)
            var = max(cell2, float(e @ cov_cal_mm2 @ e)) + float(e @ fit.cov_centre_mm2 @ e)
            u95 = K95 * math.sqrt(var)
        dev = measured - c.nominal_mm
        out.append(Value(c, measured, dev, u95, decide(dev, c.tol_mm, u95)))
    return out


def not_measured(feature: Feature, reason: str) -> list[Value]:
    """Every characteristic of a feature that gave no value: "not measured" with the reason."""
    return [Value(c, None, None, None, "not measured", reason) for c in feature.characteristics()]
