"""The simulated line's bodies and its feature sensor: fakes.body's bodies clamped in the
simulated cell, seen from where the true robot stands, and their true values (what a CMM
reports) per characteristic of the feature plan.

`SimulatedBodies.clamp(k)` clamps body k (the fixture's repeatability, seeded by the body and
how often it was clamped); `profiles(view)` moves the true robot to the view (a new stop, off
by its repeatability: fakes.cell) and returns the stripe profiles of the sweep at the view's
mirror commands, in the sensor frame; `true_value` gives the truth of a characteristic of body
k in the body's own frame. Two paths:

- geometric (`vision_model` None): the true sensor's laser planes cut the true sheet, sampled
  where the camera's rows see them, with the sensor's noise (fakes.body.feature_profiles);
- rendered: the true sensor records the sweep over the true sheet, its opening and its
  thickness (fakes.render_sheet), and the vision pipeline turns the frames into profiles with
  the calibrated sensor model (`vision_model`: stripe extraction, triangulation), as the real
  sensor's SweepFeatureSensor does, each point with its light (`rendered_profiles`). The
  frames are rendered in this process: the simulated line's GigE camera renders spheres
  only, so a body's sweep does not pass through it.
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
from fakes.render_noise import NoiseSettings
from fakes.render_sensor import TrueSensor
from fakes.render_sheet import render_feature_sweep
from vision.sensor_model import SensorModel
from vision.stripe import extract_sweep
from vision.triangulate import triangulate_profiles

F64 = NDArray[np.float64]


@dataclass
class SimulatedBodies:
    """Bodies of `plan`'s part type built by `process`, clamped in `cell`."""

    cell: SimulatedCell
    plan: FeaturePlan
    process: BuildProcess
    clamping: ClampSettings
    vision_model: SensorModel | None = None  # the rendered path's sensor model (None: geometric)

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
        self._sweeps += 1
        rng = np.random.default_rng([self.process.seed, 23, self.body.index, self._sweeps])
        feature = self.body.features[view.feature]
        if self.vision_model is not None:
            return self._rendered(view, feature, T_part_sensor, rng)
        planes = self.cell.sensor.laser_planes(view.commands_v)
        return feature_profiles(feature, self.T_part_body, T_part_sensor, planes, self.sensor, rng)

    def _rendered(
        self, view: FeatureView, f: TrueFeature, T_part_sensor: F64, rng: np.random.Generator
    ) -> list[F64]:
        T_body_feature = np.eye(4)
        T_body_feature[:3, :3] = np.column_stack([f.axis, np.cross(f.normal, f.axis), f.normal])
        T_body_feature[:3, 3] = f.position_mm
        T_camera_feature = np.linalg.inv(T_part_sensor) @ self.T_part_body @ T_body_feature
        nominal = self.plan.feature(f.id)
        assert self.vision_model is not None
        return rendered_profiles(
            T_camera_feature, f.kind, f.size_mm, nominal.thickness_mm, self.cell.sensor,
            self.vision_model, rng, np.asarray(view.commands_v, dtype=float),
        )  # fmt: skip


def rendered_profiles(
    T_camera_feature: F64,
    kind: str,
    size_mm: tuple[float, ...],
    thickness_mm: float,
    sensor: TrueSensor,
    model: SensorModel,
    rng: np.random.Generator,
    commands_v: F64,
    *,
    noise: NoiseSettings | None = None,
) -> list[F64]:
    """The rendered path of one sweep: the true sensor records the sweep at commands_v over the
    feature posed at T_camera_feature (fakes.render_sheet; `noise`: the camera's and the
    laser's, the default's when None), and the vision pipeline turns the frames into its
    profiles in the sensor frame with `model` (stripe extraction, triangulation): each point
    with its light (vision.triangulate.triangulate_profiles), which puts the edge where the
    stripe's rows stop being the top face's."""
    frames = render_feature_sweep(
        T_camera_feature, kind, size_mm, thickness_mm, sensor, rng, commands_v, noise=noise
    )
    return triangulate_profiles(extract_sweep(frames, "fast"), commands_v, model)


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
