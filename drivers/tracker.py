"""The laser-tracker family: the sphere (SMR nest) centres in the part frame, with quality data.

Backend primitives: ``_targets()``, ``_status()`` and ``_measure(target_id, timeout_s)``. Policy
here: target id validation, retry after a reconnect (a measurement has no side effect), and a
quality gate (``max_rms_mm``) that turns an over-noisy point into a DeviceFault.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceFault


@dataclass(frozen=True)
class TrackerStatus:
    ready: bool
    target_in_beam: bool
    detail: str = ""


@dataclass(frozen=True)
class TrackerMeasurement:
    """One measured point: ``point_mm`` shape (3,) in the part frame, its RMS [mm], the UTC time
    (ISO 8601) and the air temperature [deg C] and pressure [hPa] used for the refraction."""

    target_id: str
    point_mm: NDArray[np.float64]
    rms_mm: float
    time_utc: str
    temperature_c: float
    pressure_hpa: float


class Tracker(Device):
    """A laser tracker measuring fixed targets."""

    family = "tracker"

    def __init__(
        self, *, timeout_s: float = 30.0, max_rms_mm: float = 0.05, name: str = ""
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        if not max_rms_mm > 0:
            raise DeviceConfigError(f"max_rms_mm must be > 0, got {max_rms_mm!r}")
        self.max_rms_mm = float(max_rms_mm)

    def targets(self) -> list[str]:
        """The target ids the tracker knows."""
        return list(self._read_retrying(self._targets))

    def status(self) -> TrackerStatus:
        return self._read_retrying(self._status)

    def measure(self, target_id: str, timeout_s: float | None = None) -> TrackerMeasurement:
        """Measure one target; DeviceFault if its RMS exceeds ``max_rms_mm``."""
        if not isinstance(target_id, str) or not target_id:
            raise DeviceConfigError(f"target id must be a non-empty string, got {target_id!r}")
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        m = self._read_retrying(lambda: self._measure(target_id, timeout))
        if m.rms_mm > self.max_rms_mm:
            raise DeviceFault(
                f"{target_id}: RMS {m.rms_mm:.4f} mm exceeds {self.max_rms_mm:.4f} mm"
            )
        self.log.info("%s: %s at %s mm", self.name, target_id, np.round(m.point_mm, 4))
        return m

    @abstractmethod
    def _targets(self) -> list[str]: ...

    @abstractmethod
    def _status(self) -> TrackerStatus: ...

    @abstractmethod
    def _measure(self, target_id: str, timeout_s: float) -> TrackerMeasurement: ...
