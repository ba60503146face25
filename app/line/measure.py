"""The measurement of one sphere: the one piece of line code that does it, for `rvis run`, the
simulated line and the demo alike.

    move (robot) -> sensor: galvo sweep in volts with one grab per step -> vision -> home

The sensor is a seam (`SphereSensor`): `SweepSensor` sweeps the galvo, grabs a frame at each
command and measures the centre with `vision.measure.measure_sphere_from_sweep`;
`GeometricSensor` calls a function returning the centre (the simulated line's
`geometric_centre(target_id)`, for long runs without rendering). A sweep that the vision
quality checks reject raises `Rejected` (recorded and skipped by the cycle); a device error
propagates as the driver's typed error. A lost frame is re-triggered once by the camera driver.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.config.line import LineSettings, SweepSettings
from drivers.camera import Camera
from drivers.galvo import Galvo
from drivers.robot import Robot
from vision.errors import VisionError
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]


class Rejected(Exception):
    """The measurement failed the vision quality checks (`reason`); nothing is wrong with a
    device."""


@dataclass(frozen=True, eq=False)
class Reading:
    """A sphere centre in the sensor frame [mm], its quality figures and, when kept, the raw
    sweep (frames (n, H, W) and the commands [V])."""

    c_sensor_mm: F64
    quality: dict[str, Any] = field(default_factory=dict)
    frames: NDArray[Any] | None = None
    commands_v: F64 | None = None


class SphereSensor(Protocol):
    """Measures the sphere `target_id` from where the robot stands now."""

    @property
    def duration_s(self) -> float:
        """The time one measurement takes (for the window's time budget)."""
        ...

    def measure(self, target_id: str) -> Reading: ...


def set_galvo_volts(galvo: Galvo, volts: float) -> None:
    """Command the galvo DAC in volts (the one command model; vision's sensor model maps volts
    to the laser plane)."""
    galvo.set_volts(volts)


class SweepSensor:
    """The laser-line sensor: galvo sweep, one grab per command, vision."""

    def __init__(
        self,
        camera: Camera,
        galvo: Galvo,
        sensor_model: SensorModel,
        sweep: SweepSettings | None = None,
        *,
        mode: str = "fast",
        keep_frames: bool = False,
    ) -> None:
        self.camera, self.galvo, self.sensor_model = camera, galvo, sensor_model
        self.sweep = sweep or SweepSettings()
        self.mode, self.keep_frames = mode, keep_frames

    @property
    def duration_s(self) -> float:
        return self.sweep.duration_s

    def grab_sweep(self) -> tuple[NDArray[Any], F64]:
        """Frames (n, H, W) and the commands [V]; the galvo is parked at 0 V afterwards."""
        commands = np.array(self.sweep.commands_v())
        frames = []
        try:
            for v in commands:
                set_galvo_volts(self.galvo, float(v))
                frames.append(self.camera.grab(self.sweep.grab_timeout_s).image)
        finally:
            set_galvo_volts(self.galvo, 0.0)
        return np.stack(frames), commands

    def measure(self, target_id: str) -> Reading:
        frames, commands = self.grab_sweep()
        try:
            m = measure_sphere_from_sweep(frames, commands, self.sensor_model, mode=self.mode)
        except VisionError as exc:
            raise Rejected(f"{type(exc).__name__}: {exc}") from exc
        quality = {
            **dataclasses.asdict(m.quality),
            "n_frames_used": m.n_frames_used,
            "n_saturated": m.n_saturated,
            "sigma_mm": float(np.sqrt(np.trace(m.cov_mm2))),
        }
        keep = self.keep_frames
        return Reading(m.c_sensor_mm, quality, frames if keep else None, commands if keep else None)


class GeometricSensor:
    """A sensor that is a function of the target id (the simulated line's geometric path)."""

    def __init__(self, centre: Callable[[str], ArrayLike], duration_s: float = 1.2) -> None:
        self._centre = centre
        self._duration_s = float(duration_s)

    @property
    def duration_s(self) -> float:
        return self._duration_s

    def measure(self, target_id: str) -> Reading:
        c = np.asarray(self._centre(target_id), dtype=np.float64).reshape(3)
        return Reading(c, {"path": "geometric"})


class SphereMeasurer:
    """Robot + sensor: move to a configuration, measure a sphere, go home."""

    def __init__(self, robot: Robot, sensor: SphereSensor, line: LineSettings) -> None:
        self.robot, self.sensor, self.line = robot, sensor, line
        self.home_deg = np.array(line.home_deg, dtype=np.float64)

    def move_to(self, q_deg: ArrayLike) -> None:
        self.robot.move_joints(q_deg, speed_pct=self.line.speed_pct)

    def go_home(self) -> None:
        if not self.at_home():
            self.move_to(self.home_deg)

    def at_home(self) -> bool:
        q = self.robot.joints_deg()
        return bool(np.all(np.abs(q - self.home_deg) <= self.line.home_tol_deg))

    def measure_at(self, q_deg: ArrayLike, target_id: str) -> Reading:
        """Move to `q_deg` and measure `target_id` (the robot stays there)."""
        self.move_to(q_deg)
        return self.sensor.measure(target_id)

    def measure_one(self, q_deg: ArrayLike, target_id: str) -> Reading:
        """Move, measure and come home (also when vision rejects the sweep; after a device
        error the robot is not moved again)."""
        try:
            reading = self.measure_at(q_deg, target_id)
        except Rejected:
            self.go_home()
            raise
        self.go_home()
        return reading


class SweepFeatureSensor:
    """A body feature's sweep on a real sensor (app.inspect.measure.FeatureSensor): one grab at
    each of the view's mirror commands, the stripe of each frame extracted and triangulated
    into one profile (sensor frame, in the camera's row order, each point with its light:
    vision.triangulate.triangulate_profiles); the galvo parked at 0 V after.
    The robot is already at the view."""

    def __init__(
        self,
        camera: Camera,
        galvo: Galvo,
        sensor_model: SensorModel,
        *,
        grab_timeout_s: float = 1.0,
        mode: str = "fast",
    ) -> None:
        self.camera, self.galvo, self.sensor_model = camera, galvo, sensor_model
        self.grab_timeout_s, self.mode = grab_timeout_s, mode

    def profiles(self, view: Any) -> list[F64]:
        from vision.stripe import extract_sweep
        from vision.triangulate import triangulate_profiles

        commands = np.asarray(view.commands_v, dtype=float)
        frames = []
        try:
            for v in commands:
                set_galvo_volts(self.galvo, float(v))
                frames.append(self.camera.grab(self.grab_timeout_s).image)
        finally:
            set_galvo_volts(self.galvo, 0.0)
        # each point with its light: the edge where the stripe's rows stop being the face's
        return triangulate_profiles(extract_sweep(frames, self.mode), commands, self.sensor_model)
