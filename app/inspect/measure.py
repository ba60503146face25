"""Measuring a clamped body: each feature of the plan from its view, its values computed from the
raw data (the joints and the sensor's points), and the same computation again from stored raw
data with other parameters (re-evaluation after a step found later is corrected).

Two stages. At the cell (`extract`): the sweep's profiles give the feature's points in the
sensor frame (vision.features.extract_points: the sheet's points and the edge points, a few
kilobytes), looked for around the nominal as the parameters in force put it in the sensor
frame; these points, the view's joints and the cell's temperature are the raw data stored with
the body. Then, now or again later (`evaluate`): the points mapped to the part frame with a
calibration at the view's joints, the feature fitted there, its values with their U95 and
decisions (app.inspect.values). A feature the vision refuses gives "not measured" with the
typed reason; the body's other values stand.

`FeatureSensor` is what the cell does at a view: move the robot there and sweep the galvo; on
the simulated line the geometric path (app.sim.bodies), on a real cell the camera and galvo.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from app.api import Calibration
from app.inspect.plan import Feature, FeaturePlan
from app.inspect.values import NO_NOISE, StopNoise, Value, feature_values, not_measured
from app.inspect.views import FeatureView, InspectionPlan
from calib.repeatability import JOINT_OFFSETS, joint_sigma_rad
from vision.errors import FeatureRefused
from vision.features import (
    FeatureFit,
    FeaturePoints,
    FeatureSettings,
    extract_points,
    fit_feature,
)

F64 = NDArray[np.float64]


#: the shared error's covariance (3, 3) [mm^2] of a point measured now, seen at c_sensor_mm
#: (3,) from q_deg (6,) at temp_c (app.line.estimate.CellEstimate.point_cov_mm2); None: the
#: statement speaks
PointCov = Callable[[F64, F64, float | None], F64 | None]


class FeatureSensor(Protocol):
    """Moves the robot to a view's joints and sweeps the galvo over the feature: the stripe
    profiles (each (n_i, 3), ordered along the stripe) in the sensor frame, or (n_i, 7) with
    each point's light (vision.triangulate.triangulate_profiles: the edge from the stripe's
    light, vision.sheet)."""

    def profiles(self, view: FeatureView) -> list[F64]: ...


@dataclass(frozen=True)
class RawFeature:
    """What a feature's values are computed from: the view's joints q_deg (6,), the cell's
    temperature [degC] (None: not known) and the feature's points in the sensor frame, or why
    the sweep gave none (`refused`: a FeatureRefused's text); `stop`: which of the view's
    stops (app.inspect.views: a feature measured from several is their fits' mean)."""

    feature: str
    q_deg: F64
    temp_c: float | None
    points: FeaturePoints | None
    refused: str = ""
    stop: int = 0


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


def extract(
    cal: Calibration,
    feature: Feature,
    q_deg: F64,
    profiles: Sequence[F64],
    temp_c: float | None = None,
    settings: FeatureSettings | None = None,
    stop: int = 0,
) -> RawFeature:
    """The raw data of one feature from its sweep's profiles (sensor frame) at q_deg (its
    view's `stop`-th): its points, found around the nominal as `cal` puts it in the sensor
    frame."""
    T = cal.sensor_pose(q_deg, temp_c)[0]
    R, t = T[:3, :3], T[:3, 3]
    nominal_s, normal_s = R.T @ (feature.position_mm - t), R.T @ feature.normal
    try:
        points = extract_points(
            feature.type, profiles, nominal_s, normal_s, feature.size_mm, settings
        )
    except FeatureRefused as exc:
        return RawFeature(feature.id, q_deg, temp_c, None, str(exc), stop)
    return RawFeature(feature.id, q_deg, temp_c, points, stop=stop)


def evaluate(
    cal: Calibration,
    feature: Feature,
    raw: RawFeature | Sequence[RawFeature],
    statement_u95_mm: float,
    settings: FeatureSettings | None = None,
    noise: StopNoise = NO_NOISE,
    clamp_sd_mm: float = 0.0,
    shared: PointCov | None = None,
    sigma_rad: float | None = None,
) -> list[Value]:
    """The values of one feature from its raw data with the calibration `cal` (module
    docstring): from several stops, the mean of their fits (each stop's robot error is its
    own: the fit's own covariance and a size's sd fall with their number, and so does the
    robot's repeatability at the view, the data sheet's RP `noise.repeatability_mm` through the
    model, which takes the place of the statement's own measurement noise:
    app.inspect.values; clamp_sd_mm: the fixture's clamping repeatability, the plan's; shared:
    the estimator's shared error at the view, when it speaks; sigma_rad: the joints' sigma
    for `noise.repeatability_mm`, when the caller has it); a stop the vision refused is left
    out, all refused: "not measured" with the first one's reason."""
    raws = [raw] if isinstance(raw, RawFeature) else list(raw)
    fits, refused, at = [], [], None
    for r in raws:
        if r.points is None:
            refused.append(r.refused)
            continue
        T = cal.sensor_pose(r.q_deg, r.temp_c)[0]
        try:
            fits.append(
                fit_feature(
                    feature.type,
                    r.points.transformed(T),
                    feature.position_mm,
                    feature.normal,
                    feature.size_mm,
                    feature.axis if feature.type == "slot" else None,
                    settings,
                )
            )
        except FeatureRefused as exc:
            refused.append(str(exc))
            continue
        at = at or (r.q_deg, T)
    if not fits or at is None:
        return not_measured(feature, refused[0] if refused else "no sweep")
    fit = mean_fit(fits)
    q_deg, T = at
    c_sensor = T[:3, :3].T @ (fit.centre_mm - T[:3, 3])
    cov, J_joints = _at_point(cal, q_deg, c_sensor, noise.repeatability_mm > 0.0)
    repeat = None
    if J_joints is not None:
        if sigma_rad is None:
            sigma_rad = joint_sigma_rad(cal.model, cal.x, noise.repeatability_mm)
        repeat = sigma_rad**2 * (J_joints @ J_joints.T)
    at_view = None if shared is None else shared(q_deg, c_sensor, raws[0].temp_c)
    return feature_values(
        feature, fit, cov, statement_u95_mm, len(fits), repeat, noise.statement_noise_mm,
        clamp_sd_mm, at_view, noise.edge_u(feature.type),
    )  # fmt: skip


def mean_fit(fits: Sequence[FeatureFit]) -> FeatureFit:
    """The mean of one feature's fits from independent stops: centre, normal, sizes and a
    surface point's deviation averaged; the fit's own covariance and the sizes' sd divided by
    their number (the robot's error at each stop is part of what the fits' scatter holds
    apart: the cell's statement keeps the parameters' share, app.inspect.values)."""
    if len(fits) == 1:
        return fits[0]
    n = len(fits)
    normal = np.mean([f.normal for f in fits], axis=0)
    return dataclasses.replace(
        fits[0],
        centre_mm=np.mean([f.centre_mm for f in fits], axis=0),
        normal=normal / np.linalg.norm(normal),
        size_mm=tuple(float(v) for v in np.mean([f.size_mm for f in fits], axis=0))
        if fits[0].size_mm
        else (),
        deviation_mm=float(np.mean([f.deviation_mm for f in fits])),
        cov_centre_mm2=np.mean([f.cov_centre_mm2 for f in fits], axis=0) / n,
        sd_size_mm=tuple(
            float(v) / math.sqrt(n) for v in np.mean([f.sd_size_mm for f in fits], axis=0)
        )
        if fits[0].sd_size_mm
        else (),
        n_edge_points=sum(f.n_edge_points for f in fits),
    )


def calibration_cov(cal: Calibration, q_deg: F64, c_sensor_mm: F64) -> F64:
    """The identification's covariance at the point c_sensor_mm seen from q_deg (3, 3) [mm^2]
    (zero without one)."""
    return _at_point(cal, q_deg, c_sensor_mm, False)[0]


def _at_point(
    cal: Calibration, q_deg: F64, c_sensor_mm: F64, joints: bool
) -> tuple[F64, F64 | None]:
    """calibration_cov's covariance, and with joints the point's Jacobian (3, 6) in the joints'
    offsets (else None): one Jacobian of the model for both."""
    names, cov = cal.covariance if cal.covariance is not None else ([], None)
    active = list(names) + [n for n in JOINT_OFFSETS if joints and n not in names]
    if not active:
        return np.zeros((3, 3)), None
    J = cal.model.point_jacobian(cal.x, q_deg[None], c_sensor_mm[None], active)[0]
    out: F64 = np.zeros((3, 3)) if cov is None else J[:, : len(names)] @ cov @ J[:, : len(names)].T
    if not joints:
        return out, None
    return out, J[:, [active.index(n) for n in JOINT_OFFSETS]]


def measure_body(
    body: str,
    cal: Calibration,
    plan: FeaturePlan,
    views: InspectionPlan,
    sensor: FeatureSensor,
    statement_u95_mm: float,
    temp_c: float | None = None,
    noise: StopNoise = NO_NOISE,
) -> BodyResult:
    """Every feature of `plan` on the clamped body, along the route, the cell at temp_c
    [degC] (None: not known); a feature without a view is "not measured" (no view)."""
    raw: list[RawFeature] = []
    for v in views.views:
        f = plan.feature(v.feature)
        for k in range(v.stops):  # each a stop of its own (the sensor's robot moves there)
            raw.append(extract(cal, f, v.q_deg, sensor.profiles(v), temp_c, stop=k))
    return evaluate_body(body, cal, plan, raw, statement_u95_mm, views.unreachable, noise)


def evaluate_body(
    body: str,
    cal: Calibration,
    plan: FeaturePlan,
    raw: Sequence[RawFeature],
    statement_u95_mm: float,
    unreachable: dict[str, str] | None = None,
    noise: StopNoise = NO_NOISE,
    shared: PointCov | None = None,
) -> BodyResult:
    """A body's values from its raw data (plan order; a feature without raw data is "not
    measured" with the reason in `unreachable`, or "no view"; shared: the estimator's shared
    error at a view, `evaluate`)."""
    by_id: dict[str, list[RawFeature]] = {}
    for r in raw:
        by_id.setdefault(r.feature, []).append(r)
    values: list[Value] = []
    # the joints' sigma once a body (its 20 000 draws cost more than a feature's fit)
    rp = noise.repeatability_mm
    sigma_rad = joint_sigma_rad(cal.model, cal.x, rp) if rp > 0.0 else None
    for f in plan.features:
        stops = by_id.get(f.id)
        if not stops:
            why = (unreachable or {}).get(f.id, "no view in the plan")
            values.extend(not_measured(f, f"no view: {why}"))
        else:
            values.extend(
                evaluate(
                    cal,
                    f,
                    stops,
                    statement_u95_mm,
                    noise=noise,
                    clamp_sd_mm=plan.clamp_sd_mm,
                    shared=shared,
                    sigma_rad=sigma_rad,
                )
            )
    return BodyResult(body, tuple(values), tuple(raw))
