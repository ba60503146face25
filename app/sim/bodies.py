"""The simulated line's bodies and the geometric feature sensor: fakes.body's bodies clamped in
the simulated cell, seen from where the true robot stands, and their true values (what a CMM
reports) per characteristic of the feature plan.

`SimulatedBodies.clamp(k)` clamps body k (the fixture's repeatability, seeded by the body and
how often it was clamped); `profiles(view)` moves the true robot to the view (a new stop, off
by its repeatability: fakes.cell) and returns the stripe profiles of the true sensor's laser
planes at the view's mirror commands, with the sensor's noise; `true_value` gives the truth
of a characteristic of body k in the body's own frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.inspect.plan import Characteristic, FeaturePlan
from app.inspect.views import FeatureView
from app.sim.part import nominal_features
from fakes.body import (
    BodyShop,
    BuildProcess,
    ClampSettings,
    GeometricSensor,
    TrueBody,
    TrueFeature,
    clamp,
    feature_profiles,
)
from fakes.cell import SimulatedCell
from fakes.line import SimLine

F64 = NDArray[np.float64]


@dataclass
class SimulatedBodies:
    """Bodies of `plan`'s part type built by `process`, clamped in `cell`."""

    cell: SimulatedCell
    plan: FeaturePlan
    process: BuildProcess
    clamping: ClampSettings

    def __post_init__(self) -> None:
        self.shop = BodyShop(nominal_features(self.plan), self.process)
        s = self.cell.sensor
        vol = self.cell.spec.volume
        self.sensor = GeometricSensor(
            s.fy_px, s.cy_px, s.height_px, vol.half_x_mm / (0.5 * (vol.z_min_mm + vol.z_max_mm))
        )
        self._clamps: dict[int, int] = {}
        self._sweeps = 0
        self.body: TrueBody | None = None
        self.T_part_body = np.eye(4)

    def clamp(self, k: int) -> TrueBody:
        """Clamp body k: it becomes the body the sensor sees."""
        n = self._clamps.get(k, 0)
        self._clamps[k] = n + 1
        self.body = self.shop.body(k)
        rng = np.random.default_rng([self.process.seed, 22, k, n])
        self.T_part_body = clamp(rng, self.body, self.clamping)
        return self.body

    def profiles(self, view: FeatureView) -> list[F64]:
        """FeatureSensor: the profiles (sensor frame) of the clamped body's feature at `view`."""
        q = np.asarray(view.q_deg, dtype=float)
        return self.profiles_from(view, q + self.cell.new_stop_deg(q))

    def profiles_from(self, view: FeatureView, q_attained_deg: F64) -> list[F64]:
        """The profiles of the clamped body's feature at `view` with the true robot standing
        at q_attained_deg (the world's time now)."""
        if self.body is None:
            raise RuntimeError("no body clamped")
        T_part_sensor = self.cell.T_part_sensor(np.asarray(q_attained_deg, float)[None])[0]
        planes = self.cell.sensor.laser_planes(view.commands_v)
        self._sweeps += 1
        rng = np.random.default_rng([self.process.seed, 23, self.body.index, self._sweeps])
        feature = self.body.features[view.feature]
        return feature_profiles(feature, self.T_part_body, T_part_sensor, planes, self.sensor, rng)


def true_value(body: TrueBody, c: Characteristic, plan: FeaturePlan) -> float:
    """The truth of characteristic c of `body` (what a CMM reports, in the body's frame)."""
    f: TrueFeature = body.features[c.feature]
    if c.name in ("X", "Y", "Z"):
        return float(f.position_mm["XYZ".index(c.name)])
    if c.name == "D" or c.name == "W":
        return f.size_mm[0]
    if c.name == "L":
        return f.size_mm[1]
    nominal = plan.feature(c.feature)
    # where the nominal normal through the nominal point meets the true sheet
    cos = float(f.normal @ nominal.normal)
    return float((f.position_mm - nominal.position_mm) @ f.normal) / cos


class LineFeatureSensor:
    """The simulated line's geometric feature sensor (app.inspect.measure.FeatureSensor): the
    body the line's PLC holds now clamped in the world, seen from where the true robot stands
    (the controller's move put it there), the sweep's time passed on the line's clock."""

    def __init__(self, line: SimLine, bodies: SimulatedBodies) -> None:
        self.line, self.bodies = line, bodies

    def profiles(self, view: FeatureView) -> list[F64]:
        self.line.elapse(view.sweep_s)
        k = self.line.body_number_now() - self.line.settings.first_body
        if self.bodies.body is None or self.bodies.body.index != k:
            self.bodies.clamp(k)
        return self.bodies.profiles_from(view, self.line.cell.attained_deg())
