"""Measuring a clamped body: each feature of the plan from its view, its values computed from the
raw data (the joints and the sensor's points), and the same computation again from stored raw
data with other parameters (re-evaluation after a step found later is corrected).

`evaluate` is the one computation: the sweep's profiles (sensor frame) mapped to the part frame
with the parameters in force at the view's joints, the feature fitted there (vision.features),
its values with their U95 and decisions (app.inspect.values). A feature the vision refuses gives
"not measured" with the typed reason; the body's other values stand.

`FeatureSensor` is what the cell does at a view: move the robot there and sweep the galvo; on
the simulated line the geometric path (app.sim.bodies), on a real cell the camera and galvo.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from app.api import Calibration
from app.inspect.plan import Feature, FeaturePlan
from app.inspect.values import Value, feature_values, not_measured
from app.inspect.views import FeatureView, InspectionPlan
from vision.errors import FeatureRefused
from vision.features import FeatureSettings, measure_feature

F64 = NDArray[np.float64]


class FeatureSensor(Protocol):
    """Moves the robot to a view's joints and sweeps the galvo over the feature: the stripe
    profiles (each (n_i, 3), ordered along the stripe) in the sensor frame."""

    def profiles(self, view: FeatureView) -> list[F64]: ...


@dataclass(frozen=True)
class RawFeature:
    """What a feature's value is computed from: the view's joints q_deg (6,), the sweep's
    profiles in the sensor frame and the cell's temperature [degC] (None: not known)."""

    feature: str
    q_deg: F64
    profiles: tuple[F64, ...]
    temp_c: float | None = None


@dataclass(frozen=True)
class BodyResult:
    """A body's values (plan order) and the raw data they came from."""

    body: str
    values: tuple[Value, ...]
    raw: tuple[RawFeature, ...]

    @property
    def ok(self) -> bool:
        """No characteristic proven nonconforming and every one measured."""
        return all(v.decision in ("conforming", "undecided") for v in self.values)


def evaluate(
    cal: Calibration,
    feature: Feature,
    raw: RawFeature,
    statement_u95_mm: float,
    settings: FeatureSettings | None = None,
) -> list[Value]:
    """The values of one feature from its raw data with the calibration `cal` (module
    docstring)."""
    profiles = [p for p in raw.profiles if len(p)]
    if not profiles:
        return not_measured(feature, "no_points: the sweep gave no stripe point")
    T = cal.sensor_pose(raw.q_deg, raw.temp_c)[0]
    in_part = [p @ T[:3, :3].T + T[:3, 3] for p in profiles]
    try:
        fit = measure_feature(
            feature.type,
            in_part,
            feature.position_mm,
            feature.normal,
            feature.size_mm,
            feature.axis if feature.type == "slot" else None,
            settings,
        )
    except FeatureRefused as exc:
        return not_measured(feature, str(exc))
    c_sensor = T[:3, :3].T @ (fit.centre_mm - T[:3, 3])
    return feature_values(feature, fit, calibration_cov(cal, raw.q_deg, c_sensor), statement_u95_mm)


def calibration_cov(cal: Calibration, q_deg: F64, c_sensor_mm: F64) -> F64:
    """The identification's covariance at the point c_sensor_mm seen from q_deg (3, 3) [mm^2]
    (zero without one)."""
    if cal.covariance is None:
        return np.zeros((3, 3))
    names, cov = cal.covariance
    J = cal.model.point_jacobian(cal.x, q_deg[None], c_sensor_mm[None], names)[0]
    out: F64 = J @ cov @ J.T
    return out


def measure_body(
    body: str,
    cal: Calibration,
    plan: FeaturePlan,
    views: InspectionPlan,
    sensor: FeatureSensor,
    statement_u95_mm: float,
    temp_c: float | None = None,
) -> BodyResult:
    """Every feature of `plan` on the clamped body, along the route, the cell at temp_c
    [degC] (None: not known); a feature without a view is "not measured" (no view)."""
    raw: dict[str, RawFeature] = {}
    for v in views.views:
        raw[v.feature] = RawFeature(v.feature, v.q_deg, tuple(sensor.profiles(v)), temp_c)
    return evaluate_body(body, cal, plan, list(raw.values()), statement_u95_mm, views.unreachable)


def evaluate_body(
    body: str,
    cal: Calibration,
    plan: FeaturePlan,
    raw: Sequence[RawFeature],
    statement_u95_mm: float,
    unreachable: dict[str, str] | None = None,
) -> BodyResult:
    """A body's values from its raw data (plan order; a feature without raw data is "not
    measured" with the reason in `unreachable`, or "no view")."""
    by_id = {r.feature: r for r in raw}
    values: list[Value] = []
    for f in plan.features:
        r = by_id.get(f.id)
        if r is None:
            why = (unreachable or {}).get(f.id, "no view in the plan")
            values.extend(not_measured(f, f"no view: {why}"))
        else:
            values.extend(evaluate(cal, f, r, statement_u95_mm))
    return BodyResult(body, tuple(values), tuple(raw))
