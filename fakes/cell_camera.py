"""The frames the camera of a simulated cell sees (fakes/cell.py, the device fakes' World
protocol): the nearest sphere in front of the sensor at the robot's current stop, lit by the
laser plane of the galvo command, rendered in 12 bits with the image noise of the frame itself
(`CameraFrames._rng`: seeded by the frame, never drawn from one stream, so a commissioning step
resumed in a new process renders the very frames an uninterrupted run renders)."""

from __future__ import annotations

import hashlib
import threading
from dataclasses import replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fakes.cell_spec import CellSpec, SimSettings
from fakes.render import Lighting, SphereScene, render_sphere_sweep, sphere_scene
from fakes.render_noise import NoiseSettings, dark_frame
from fakes.render_sensor import TrueSensor

F64 = NDArray[np.float64]

#: Exposure [us] at which the renderer's laser power and ambient light are specified.
REFERENCE_EXPOSURE_US = 10_000.0
#: A camera frame reuses the previous frame's sphere scene (the costly, laser-independent part of
#: rendering) while the sphere has moved less than this in the sensor frame [mm]: during a sweep
#: the robot stands still and only the warm-up moves the sphere, by nanometres per frame.
SCENE_REUSE_MM = 1e-4
#: the renderer's frames: 12-bit digital numbers, full scale 4095
FRAME_BITS = 12
FULL_SCALE_DN = (1 << FRAME_BITS) - 1


class FramedCell(Protocol):
    """What the camera's frames need of the simulated cell (fakes.cell.SimulatedCell)."""

    noise_draw: int
    settings: SimSettings  # its seed
    spec: CellSpec  # its spheres' radius

    @property
    def sensor(self) -> TrueSensor: ...

    def joints_deg(self) -> F64: ...

    def sphere_in_view(self) -> F64 | None: ...


class CameraFrames:
    """The frames of `cell`'s camera, rendered under `lock` (the cell's, which its true sensor
    and sweeps share): the frames rendered so far per key (their noise draws) and the last
    sphere scene (`scene`, reused while the sphere stands still)."""

    def __init__(self, cell: FramedCell, lock: threading.Lock) -> None:
        self.cell, self.lock = cell, lock
        self._seen: dict[int, int] = {}  # a frame's key -> times rendered (_rng)
        self._last: tuple[int, int] = (-1, 0)  # the key and draw index rendered last
        self.scene: SphereScene | None = None

    def counts_v(
        self, width: int, height: int, exposure_us: float, gain_db: float, command_v: float
    ) -> tuple[NDArray[np.uint16], int]:
        """The frame the camera sees now as the renderer's 12-bit digital numbers and their full
        scale (`SimulatedCell.render_counts_v`)."""
        sensor = self.cell.sensor
        if width > sensor.width_px or height > sensor.height_px:
            raise ValueError(
                f"frame {width}x{height} exceeds the sensor's {sensor.width_px}x{sensor.height_px}"
            )
        exposure = exposure_us / REFERENCE_EXPOSURE_US
        gain = 10.0 ** (gain_db / 20.0)
        base = NoiseSettings(bits=FRAME_BITS)
        noise = replace(
            base, full_well_e=base.full_well_e / gain, ambient_e=base.ambient_e * exposure
        )
        light = replace(Lighting(), power=Lighting().power * exposure * gain)
        c = self.cell.sphere_in_view()
        with self.lock:
            rng = self._rng(command_v, exposure_us, gain_db)
            if c is None:
                frame = dark_frame((sensor.height_px, sensor.width_px), noise, rng)
            else:
                scene = self._scene_of(sensor, c)
                frame = render_sphere_sweep(
                    scene.c_sensor_mm,
                    scene.radius_mm,
                    sensor,
                    rng,
                    commands_v=np.array([command_v]),
                    noise=noise,
                    light=light,
                    stripe_truth=False,
                    scene=scene,
                )[0][0]
        return np.asarray(frame[:height, :width], dtype=np.uint16), FULL_SCALE_DN

    def warm_up(self) -> None:
        """Render one frame of a sphere and throw it away (no noise drawn from the cell's
        frames, no scene kept): the one-time costs of the first rendering (about 0.3 s) are
        paid now, not by the camera's first frame at a sphere, which a loaded machine would
        deliver after the driver's timeout (a commissioning resumed at its calibration)."""
        sensor = self.cell.sensor
        scene = sphere_scene(sensor, np.array([0.0, 0.0, 130.0]), self.cell.spec.sphere_radius_mm)
        with self.lock:
            render_sphere_sweep(
                scene.c_sensor_mm,
                scene.radius_mm,
                sensor,
                np.random.default_rng(0),
                commands_v=np.array([0.0]),
                noise=NoiseSettings(bits=12),
                light=Lighting(),
                stripe_truth=False,
                scene=scene,
            )

    def _rng(self, command_v: float, exposure_us: float, gain_db: float) -> np.random.Generator:
        """The noise of the frame at the current joints (module docstring): seeded by the
        cell's seed, the frame's key (joints to 0.1 deg, command to 1 uV, exposure to 0.01 us,
        gain to 0.001 dB) and how many times the key was rendered before, other frames in
        between (a frame rendered again straight after itself, as a lost frame the camera
        driver re-triggers, keeps its noise: whether a frame is lost depends on the machine's
        load, which must not change the images). Under the lock.
        The joints' grid is coarse on purpose: views of one step are degrees apart, and a view
        planned again in a resumed run differs from the first plan in its last bits (the
        parameters it is planned on do), which a fine grid would sometimes round to another
        key, another noise."""
        key = np.concatenate(
            [
                np.round(self.cell.joints_deg() * 10.0),
                np.round([command_v * 1e6, exposure_us * 100.0, gain_db * 1e3]),
            ]
        ).astype(np.int64)
        key_digest = digest(key)
        last, n = self._last
        if key_digest != last:
            n = self._seen.get(key_digest, 0)
            self._seen[key_digest] = n + 1
            self._last = (key_digest, n)
        draw = [self.cell.noise_draw] if self.cell.noise_draw else []
        return np.random.default_rng([self.cell.settings.seed, 4, key_digest, n, *draw])

    def _scene_of(self, sensor: TrueSensor, c_sensor_mm: F64) -> SphereScene:
        """The sphere scene at c_sensor_mm: the last one if the sphere moved less than
        SCENE_REUSE_MM since (the frame's centre then lags the truth by less than that)."""
        last = self.scene
        if last is None or np.max(np.abs(last.c_sensor_mm - c_sensor_mm)) >= SCENE_REUSE_MM:
            last = self.scene = sphere_scene(sensor, c_sensor_mm, self.cell.spec.sphere_radius_mm)
        return last


def digest(key: NDArray[np.int64]) -> int:
    """A key's 64-bit digest (the seed of a frame's noise or of a stop's error)."""
    return int.from_bytes(hashlib.blake2b(key.tobytes(), digest_size=8).digest(), "little")
