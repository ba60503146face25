"""The simulated cell's one truth: the error of a point measured the way the line measures it.

A point the inspection software gets has gone through the whole chain: the true sensor observes
the sphere (the laser stripes the true camera sees), the vision pipeline turns the stripes into
3-D points with the *sensor model in use* and fits the certified sphere, and the *parameters in
force* map that centre to the part frame. Its error is that part-frame point minus the true
point. `EndToEndTruth` computes exactly that without rendering: the stripes are the true
sensor's noise-free observation (`fakes.render.stripe_rows`: the plane-sphere arcs, visible and
lit, sampled at the image rows as an extractor reports them), so it is cheap enough for every
window of a rendered line and equals a rendered measurement within the rendering's noise
(tests/sim/test_truth.py).

With no sensor model (the geometric path: the sensor *is* the true centre plus noise) the
measured centre is the true one, and the figure is the kinematic error. A figure that feeds the
true centre into parameters identified with a calibrated sensor describes no real system (the
hand-eye absorbed the sensor model's small rigid error): it is not computed here, and where it is
shown at all it is labelled as the kinematic error (DESIGN.md section 10).

A view's centre through the sensor model depends on the true centre only smoothly (the model's
error is a small, smooth distortion of the sensor frame), so the correction `measured - true` of
each view is kept and computed again only when the true centre has moved by more than
`refresh_mm` (a knock, the warm-up): at 0.25 mm the cached correction is within 0.1 um of a fresh
one for a sensor model whose scale is off by 0.04 %.

On the simulated line (`true_errors_mm`, `true_rmse_mm`): that error at the line's validation
positions for given parameters; `robot_floor_mm`: what no calibration gets below (the true
robot's stops alone).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.validation import rmse
from fakes.render import stripe_rows
from fakes.render_sensor import TrueSensor
from vision.errors import VisionError
from vision.measure import CERTIFIED_RADIUS_MM
from vision.sensor_model import SensorModel
from vision.spherefit import FitThresholds, fit_sphere
from vision.stripe import StripePoints
from vision.triangulate import triangulate_sweep

if TYPE_CHECKING:
    from fakes.line import SimLine

F64 = NDArray[np.float64]

#: The dimmest stripe an extractor keeps, as a Lambertian factor: at the renderer's default
#: power (0.35 of full well) a peak of 12 DN of 255 is 0.134 of the normal-incidence brightness.
MIN_LAMBERT = 0.134


@dataclass(frozen=True)
class Observed:
    """One view through the sensor model: the centre it reports [mm] in S, or None with the
    reason the vision checks would give."""

    c_sensor_mm: F64 | None
    reason: str = ""


def observe(
    sensor: TrueSensor,
    model: SensorModel,
    c_true_mm: ArrayLike,
    commands_v: Sequence[float] | F64,
    radius_mm: float = CERTIFIED_RADIUS_MM,
    thresholds: FitThresholds | None = None,
) -> Observed:
    """The centre the vision pipeline reports for a sphere whose true centre is c_true_mm (3,)
    in the true sensor frame, seen by the true sensor and measured with `model`."""
    cmds = np.asarray(commands_v, dtype=np.float64)
    rows = stripe_rows(sensor, np.asarray(c_true_mm, dtype=np.float64), radius_mm, cmds)
    stripes = []
    for r in rows:
        keep = r.lambert >= MIN_LAMBERT
        u, v = r.u_px[keep], r.v_px[keep]
        stripes.append(StripePoints(u, v, np.ones_like(u), np.ones_like(u)))
    X, _ = triangulate_sweep(stripes, cmds, model)
    try:
        fit = fit_sphere(X, radius_mm, thresholds)
    except VisionError as exc:
        return Observed(None, f"{type(exc).__name__}: {exc}")
    return Observed(fit.centre_mm)


@dataclass
class EndToEndTruth:
    """The error of points measured the way the line measures them.

    sensor: the true sensor (what observes); sensor_model: the sensor calibration in use (None:
    the geometric path, whose sensor reports the true centre); commands_v: the line's galvo
    sweep [V]; refresh_mm: how far a view's true centre may move before its correction is
    computed again (module docstring)."""

    sensor: TrueSensor
    sensor_model: SensorModel | None
    commands_v: tuple[float, ...]
    radius_mm: float = CERTIFIED_RADIUS_MM
    refresh_mm: float = 0.25
    _cache: dict[int, tuple[F64, F64 | None, str]] = field(default_factory=dict, repr=False)

    @property
    def kinematic_only(self) -> bool:
        """True on the geometric path: the figure is the kinematic error."""
        return self.sensor_model is None

    def centres(self, c_true_mm: F64) -> tuple[F64, NDArray[np.bool_]]:
        """Measured centres (n, 3) in S for true centres (n, 3) of the views 0..n-1 (the same
        view index for the same view across calls) and which views the vision accepts."""
        c_true = np.asarray(c_true_mm, dtype=np.float64).reshape(-1, 3)
        if self.sensor_model is None:
            return c_true.copy(), np.ones(len(c_true), dtype=bool)
        out = np.full_like(c_true, np.nan)
        ok = np.zeros(len(c_true), dtype=bool)
        for i, c in enumerate(c_true):
            delta = self._delta(i, c)
            if delta is not None:
                out[i], ok[i] = c + delta, True
        return out, ok

    def _delta(self, i: int, c: F64) -> F64 | None:
        hit = self._cache.get(i)
        if hit is not None and np.linalg.norm(hit[0] - c) <= self.refresh_mm:
            return hit[1]
        assert self.sensor_model is not None
        seen = observe(self.sensor, self.sensor_model, c, self.commands_v, self.radius_mm)
        delta = None if seen.c_sensor_mm is None else seen.c_sensor_mm - c
        self._cache[i] = (c.copy(), delta, seen.reason)
        return delta

    def rejected(self) -> dict[int, str]:
        """The views (index -> reason) the vision checks reject, as last computed."""
        return {i: reason for i, (_, d, reason) in self._cache.items() if d is None}

    def errors_mm(
        self,
        model: Any,
        x: F64,
        q_deg: F64,
        c_true_mm: F64,
        p_true_mm: F64,
        temp_c: F64 | None = None,
    ) -> F64:
        """Part-frame errors (m, 3) [mm] of the accepted views: the point the system reports
        (model with parameters x, the measured centre) minus the true point."""
        c, ok = self.centres(c_true_mm)
        temp = None if temp_c is None else np.asarray(temp_c)[ok]
        p = model.points_part(x, np.asarray(q_deg)[ok], c[ok], temp_c=temp)
        out: F64 = p - np.asarray(p_true_mm)[ok]
        return out

    def rmse_mm(self, *args: Any, **kwargs: Any) -> float:
        """RMS of the Euclidean errors of `errors_mm` (NaN when no view is accepted)."""
        return rmse_or_nan(self.errors_mm(*args, **kwargs))


def true_errors_mm(
    line: SimLine, truth: EndToEndTruth, model: Any, x: F64, t_s: float | None = None
) -> F64:
    """The end-to-end true errors (m, 3) [mm] of `model` with parameters x at the line's
    validation positions at sim time t_s (default now; the cell's temperature as the PLC reads
    it): each position's sphere observed by the true sensor, measured through the sensor model
    in use (`truth`), mapped with x."""
    return true_errors_each_mm(line, truth, model, [x], t_s)[0]


def true_errors_each_mm(
    line: SimLine, truth: EndToEndTruth, model: Any, xs: Sequence[F64], t_s: float | None = None
) -> list[F64]:
    """`true_errors_mm` of each parameter vector in xs on one observation of the validation
    positions (the robot's stops there at t_s drawn once, as the parameters are compared on the
    same measurements)."""
    v = line.truth.validation
    c = line.truth.validation_centres_sensor_mm(t_s)
    temp = np.full(len(v.q_deg), line.truth.temp_c(t_s))
    return [truth.errors_mm(model, x, v.q_deg, c, v.p_part_mm, temp) for x in xs]


def robot_floor_mm(line: SimLine, draws: int = 50) -> float:
    """The robot's floor [mm]: the RMS error of the line's validation positions measured with
    exact parameters by a perfect sensor, the true robot's stops alone (each position from
    `draws` seeded stops of its repeatability): what no calibration gets below."""
    v, cell = line.truth.validation, line.truth.cell
    rng = np.random.default_rng([cell.settings.seed, 9283])
    exact = cell.centre_in_sensor(v.q_deg, v.p_part_mm, 0.0)
    sq = []
    for _ in range(draws):
        stops = v.q_deg + cell.repeatability.draw_deg(rng, len(v.q_deg))
        sq.append(np.sum((cell.centre_in_sensor(stops, v.p_part_mm, 0.0) - exact) ** 2, axis=1))
    return float(np.sqrt(np.mean(sq)))


def true_rmse_mm(
    line: SimLine, truth: EndToEndTruth, model: Any, x: F64, t_s: float | None = None
) -> float:
    """RMS [mm] of `true_errors_mm` (NaN when no view is accepted)."""
    return rmse_or_nan(true_errors_mm(line, truth, model, x, t_s))


def rmse_or_nan(errors_mm: F64) -> float:
    """RMS [mm] of the Euclidean errors (m, 3); NaN for none (no view accepted)."""
    return rmse(errors_mm) if len(errors_mm) else float("nan")
