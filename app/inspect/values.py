"""A fitted feature's characteristic values, each with its task-specific U95 and its decision
per ISO 14253-1.

The U95 of a value along a direction e of the part frame (a position X, Y, Z: the axis; a
surface point's N: the nominal normal) is k sqrt(max(sigma_cell^2 - sigma_m^2, e' C_cal e) +
e' C_rep e / n + e' C_fit e + s_clamp^2), k the two-sided 95 % factor of one coordinate (1.96):
- sigma_cell: the cell's statement for a point measured now (a U95 of the 3-D error's norm, the
  one estimator's or the commissioning's workspace validation's), per coordinate: U95 / 2.80
  (calib.uncertainty.norm_quantile). It holds every error of a point measured now: the
  parameters' at the point, what the model leaves out, and the measurement's own noise;
- sigma_m: that own noise of the statement's measurement, per coordinate (`StopNoise`: the
  estimator's, app.line.estimate.sphere_sigma_mm, a sphere centre's: the robot's
  repeatability at the sphere's stop and the sphere's sensing). It is the sphere's, not the
  feature's: the value replaces it with its own, the two terms after the max.
  sigma_cell^2 - sigma_m^2 is what every point measured now shares, wherever it is measured;
- C_cal (3, 3): the identification's covariance propagated to the feature's centre at its view
  (J P J', as `rvis.Calibration.u95_mm` propagates it): the parameters' part alone, but at this
  pose. Added to the statement's share it would count the parameters twice; the larger of the
  two stands, so a pose where the parameters are less certain than on average is never
  understated;
- C_rep (3, 3): the robot's repeatability at the feature's view (the data sheet's RP as joint
  errors through the model, app.inspect.views), over the n stops whose fits are averaged (each
  stop's robot error is its own). The views are chosen where the robot repeats best, so this
  is often less than a sphere's stop's; without RP (0) the statement's sigma_m stands in, once
  a stop;
- C_fit (3, 3): the feature fit's own covariance (vision.features): the feature's sensing,
  which the sphere's does not contain;
- s_clamp: the fixture's clamping repeatability (the feature plan's `clamp_sd_mm`): the
  value is in the fixture's frame, the body's truth (a CMM's) in its own; the spheres stand in
  the cell and hold none of it.
In the in-line cycle the one estimator speaks for the shared part at the feature's own view
(`shared_cov_mm2`, calib.cellstate.CellState.point_cov_mm2): e' S e with S = J d d' J' +
J P J' + s_u^2 I, J the model's point Jacobian at the view, (d, P) the estimator's offset of the
parameters from the version in force and their covariance, s_u its unmodelled term. The
statement is a norm averaged over the spheres' poses and directions (its trace / 3 per
coordinate): the split above assumes the error the same in every direction and at every pose,
while a drifting cell's error is not (a warming arm grows along its own axes). The larger of
the two stands in the value: e' S e where the estimator sees more along e at this view than the
statement's share: the estimator sees the spheres' poses, and at the body's it may see less
than there is (docs/results/body.md). The offset d is an estimate the version in force does not
correct: it is counted as a variance (b^2 with b = e' J d), the root-sum-square way of stating
an uncorrected bias (Phillips, Eberhardt and Parry, J. Res. NIST 102 (1997) 577).

A size (D, W, L) is a distance within one view: the pose's error moves both edges alike, so
its U95 is k sqrt(sd_fit^2 + 2 u_edge^2): the fit's own sd holds the edge points' random
placement within a stripe sample; u_edge is the type-B uncertainty of what stays systematic on
every edge point of one side, a round hole's (`[sensor] edge_u_mm`) or a slot's
(`edge_u_slot_mm`: a slot's fit rests on two straight sides and two end arcs, where a circle's
averages its edge all round), default `EDGE_U_MM`: the sensor's, measured on certified bores
and slots as bench/edge.py measures the simulated rendered sensor's.

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
class StopNoise:
    """The measurement's own noise in a value's U95 (module docstring): the robot's
    repeatability, the data sheet's ISO 9283 RP [mm] (0: not known), and the cell's statement's
    own measurement noise per coordinate [mm] (sigma_m: the estimator's,
    app.line.estimate.sphere_sigma_mm; 0: the statement holds none apart), and the sensor's
    edge placement allowances per side in a size's U95 [mm]: a round hole's and a slot's
    ([sensor] edge_u_mm, edge_u_slot_mm)."""

    repeatability_mm: float = 0.0
    statement_noise_mm: float = 0.0
    edge_u_mm: float = EDGE_U_MM
    edge_u_slot_mm: float = EDGE_U_MM

    def edge_u(self, feature_type: str) -> float:
        """The edge placement allowance per side [mm] of a feature of this type's sizes."""
        return self.edge_u_slot_mm if feature_type == "slot" else self.edge_u_mm


#: no noise held apart: the statement as it is, once a stop
NO_NOISE = StopNoise()


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
    statement_noise_mm: float = 0.0,
    clamp_sd_mm: float = 0.0,
    shared_cov_mm2: F64 | None = None,
    edge_u_mm: float = EDGE_U_MM,
) -> list[Value]:
    """The values of `feature` from its fit in the part frame (module docstring); cov_cal_mm2
    (3, 3): the calibration's covariance at the feature's centre; statement_u95_mm: the
    cell's, statement_noise_mm its own measurement's noise per coordinate; a fit averaged over
    `stops` stops (app.inspect.measure.mean_fit), cov_repeat_mm2 (3, 3): the robot's
    repeatability at one stop of the view (None: not known, the statement's noise stands in);
    clamp_sd_mm: the fixture's clamping repeatability (the plan's); shared_cov_mm2 (3, 3): the
    estimator's shared error at the feature's view (None: the statement's share stands in);
    edge_u_mm: the sensor's edge placement allowance per side for this feature's type, in a
    size's U95 (StopNoise.edge_u)."""
    sigma2 = cell_sigma_mm(statement_u95_mm) ** 2
    noise2 = min(statement_noise_mm**2, sigma2)
    out = []
    sizes = iter(zip(fit.size_mm, fit.sd_size_mm, strict=True))
    for c in feature.characteristics():
        if c.kind == "size":
            size, sd = next(sizes)
            measured = size
            u95 = K95 * math.sqrt(sd**2 + 2.0 * edge_u_mm**2)
        else:
            if c.name == "N":
                e = feature.normal
                measured = fit.deviation_mm
            else:
                e = np.eye(3)["XYZ".index(c.name)]
                measured = float(fit.centre_mm["XYZ".index(c.name)])
            own = noise2 if cov_repeat_mm2 is None else float(e @ cov_repeat_mm2 @ e)
            shared = max(sigma2 - noise2, float(e @ cov_cal_mm2 @ e))
            if shared_cov_mm2 is not None:  # the estimator's, at the view, where it says more
                shared = max(shared, float(e @ shared_cov_mm2 @ e))
            var = shared + own / stops + float(e @ fit.cov_centre_mm2 @ e) + clamp_sd_mm**2
            u95 = K95 * math.sqrt(var)
        dev = measured - c.nominal_mm
        out.append(Value(c, measured, dev, u95, decide(dev, c.tol_mm, u95)))
    return out


def not_measured(feature: Feature, reason: str) -> list[Value]:
    """Every characteristic of a feature that gave no value: "not measured" with the reason."""
    return [Value(c, None, None, None, "not measured", reason) for c in feature.characteristics()]
