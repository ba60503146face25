"""The camera family: configure (region, exposure, gain, pixel format, trigger) and grab frames.

Backend primitives: ``_sensor_size()``, ``_apply(settings) -> CameraSettings`` (returns what the
camera actually accepted), ``_trigger()`` (software trigger) and ``_grab(timeout_s) -> Frame``.
Policy here: settings validation, software triggering, one re-trigger after a lost frame (safe:
a software-triggered grab has no side effect), logging.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceTimeout

PixelFormat = Literal["Mono8", "Mono12", "Mono16"]
TriggerMode = Literal["free", "software", "hardware"]
PIXEL_FORMATS: tuple[str, ...] = ("Mono8", "Mono12", "Mono16")
TRIGGER_MODES: tuple[str, ...] = ("free", "software", "hardware")


@dataclass(frozen=True)
class CameraSettings:
    """Acquisition settings. ``region`` is (x, y, width, height) in pixels, None = full sensor."""

    region: tuple[int, int, int, int] | None = None
    exposure_us: float = 10_000.0
    gain_db: float = 0.0
    pixel_format: PixelFormat = "Mono8"
    trigger: TriggerMode = "software"
    trigger_line: str = "Line0"
    buffers: int = 4

    def validated(self, sensor_wh: tuple[int, int]) -> CameraSettings:
        if self.pixel_format not in PIXEL_FORMATS:
            raise DeviceConfigError(f"pixel_format must be one of {PIXEL_FORMATS}")
        if self.trigger not in TRIGGER_MODES:
            raise DeviceConfigError(f"trigger must be one of {TRIGGER_MODES}")
        if not (self.exposure_us > 0 and np.isfinite(self.exposure_us)):
            raise DeviceConfigError(f"exposure_us must be > 0, got {self.exposure_us}")
        if not (self.gain_db >= 0 and np.isfinite(self.gain_db)):
            raise DeviceConfigError(f"gain_db must be >= 0, got {self.gain_db}")
        if self.buffers < 1:
            raise DeviceConfigError("buffers must be >= 1")
        region = self.region or (0, 0, *sensor_wh)
        x, y, w, h = (int(v) for v in region)
        if x < 0 or y < 0 or w <= 0 or h <= 0 or x + w > sensor_wh[0] or y + h > sensor_wh[1]:
            raise DeviceConfigError(f"region {region} outside the {sensor_wh} sensor")
        return replace(self, region=(x, y, w, h))


@dataclass(frozen=True)
class Frame:
    """One image: ``image`` shape (height, width), uint8 (Mono8) or uint16 (Mono12/16)."""

    image: NDArray[np.uint8] | NDArray[np.uint16]
    frame_id: int
    timestamp_ns: int
    exposure_us: float
    gain_db: float


class Camera(Device):
    """A monochrome area camera."""

    family = "camera"

    def __init__(
        self, *, settings: CameraSettings | None = None, timeout_s: float = 2.0, name: str = ""
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        self._wanted = settings or CameraSettings()
        self._settings: CameraSettings | None = None

    @property
    def settings(self) -> CameraSettings:
        """The settings in force (as read back from the camera)."""
        self._check_open()
        assert self._settings is not None
        return self._settings

    def open(self) -> Camera:
        super().open()
        if self._settings is None:
            try:
                self.configure(self._wanted)
            except BaseException:
                self.close()
                raise
        return self

    def close(self) -> None:
        self._settings = None
        super().close()

    def sensor_size(self) -> tuple[int, int]:
        """(width, height) of the full sensor in pixels."""
        self._check_open()
        return self._sensor_size()

    def configure(self, settings: CameraSettings) -> CameraSettings:
        """Apply ``settings`` and return what the camera accepted."""
        self._check_open()
        wanted = settings.validated(self._sensor_size())
        with self._lock:
            self._settings = self._apply(wanted)
        self.log.info("%s: configured %s", self.name, self._settings)
        return self._settings

    def grab(self, timeout_s: float | None = None) -> Frame:
        """Trigger (software mode) and return the next frame; DeviceTimeout if none arrives."""
        self._check_open()
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        with self._lock:
            software = self.settings.trigger == "software"
            if software:
                self._trigger()
            try:
                return self._grab(timeout)
            except DeviceTimeout:
                if not software:
                    raise
                self.log.warning("%s: frame lost, re-triggering once", self.name)
                self._trigger()
                return self._grab(timeout)

    @abstractmethod
    def _sensor_size(self) -> tuple[int, int]: ...

    @abstractmethod
    def _apply(self, settings: CameraSettings) -> CameraSettings: ...

    @abstractmethod
    def _trigger(self) -> None: ...

    @abstractmethod
    def _grab(self, timeout_s: float) -> Frame: ...
