"""The galvanometer family: set the mirror angle through a DAC voltage.

``GalvoCalibration`` maps the mirror angle [deg] to the DAC command [V] with a polynomial (the
command-to-angle calibration; REFERENCE.md: calibrate the nonlinearity with a polynomial or a
table) and holds the angle and voltage limits. Backend primitives: ``_identify()``,
``_set_volts(v)``, ``_get_volts()``, ``_errors() -> list[(code, message)]`` (the DAC's error
queue). Policy here: limits (MotionRefused, nothing sent), error-queue check after every set,
retry after a reconnect (setting a voltage is idempotent).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

import numpy as np

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceFault, MotionRefused


@dataclass(frozen=True)
class GalvoCalibration:
    """volts = sum(c[k] * angle_deg**k); monotonic increasing inside the angle limits."""

    coefficients: tuple[float, ...] = (0.0, 0.5)  # 0.5 V per mechanical degree
    angle_limits_deg: tuple[float, float] = (-20.0, 20.0)
    volt_limits: tuple[float, float] = (-10.0, 10.0)

    def __post_init__(self) -> None:
        lo, hi = self.angle_limits_deg
        if not (lo < hi and len(self.coefficients) >= 2):
            raise DeviceConfigError("galvo calibration needs lo < hi and a degree >= 1 polynomial")
        grid = np.linspace(lo, hi, 257)
        volts = self._poly(grid)
        if np.any(np.diff(volts) <= 0):
            raise DeviceConfigError("galvo calibration is not monotonic inside the angle limits")
        if volts[0] < self.volt_limits[0] or volts[-1] > self.volt_limits[1]:
            raise DeviceConfigError("galvo angle limits exceed the DAC voltage range")

    def _poly(self, angle_deg: np.ndarray) -> np.ndarray:
        return np.polynomial.polynomial.polyval(angle_deg, self.coefficients)

    def angle_to_volts(self, angle_deg: float) -> float:
        return float(self._poly(np.asarray(angle_deg, dtype=np.float64)))

    def volts_to_angle(self, volts: float) -> float:
        """Inverse map by bisection on the monotonic polynomial (to 1e-9 deg)."""
        lo, hi = self.angle_limits_deg
        v_lo, v_hi = self.angle_to_volts(lo), self.angle_to_volts(hi)
        if not v_lo - 1e-9 <= volts <= v_hi + 1e-9:
            raise DeviceFault(f"DAC reads {volts} V, outside the calibrated range")
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if self.angle_to_volts(mid) < volts:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)


class Galvo(Device):
    """A one-mirror galvanometer commanded by a DAC voltage."""

    family = "galvo"

    def __init__(
        self,
        *,
        calibration: GalvoCalibration | None = None,
        timeout_s: float = 1.0,
        name: str = "",
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        self.calibration = calibration or GalvoCalibration()

    def describe(self) -> str:
        return self._read_retrying(self._identify)

    def set_angle_deg(self, angle_deg: float) -> float:
        """Command the mirror angle [deg]; returns the voltage sent."""
        self._check_open()
        lo, hi = self.calibration.angle_limits_deg
        if not (np.isfinite(angle_deg) and lo <= angle_deg <= hi):
            raise MotionRefused(f"galvo angle {angle_deg} outside [{lo}, {hi}] deg")
        volts = self.calibration.angle_to_volts(float(angle_deg))

        def _set() -> None:
            self._set_volts(volts)
            self._raise_errors()

        self._read_retrying(_set)  # idempotent: safe to repeat after a reconnect
        return volts

    def angle_deg(self) -> float:
        """The mirror angle [deg] the DAC is commanding now."""
        return self.calibration.volts_to_angle(self._read_retrying(self._get_volts))

    def _raise_errors(self) -> None:
        errors = self._errors()
        if errors:
            code, message = errors[0]
            raise DeviceFault(f"{self.name}: DAC error {code}: {message}", code=code)

    @abstractmethod
    def _identify(self) -> str: ...

    @abstractmethod
    def _set_volts(self, volts: float) -> None: ...

    @abstractmethod
    def _get_volts(self) -> float: ...

    @abstractmethod
    def _errors(self) -> list[tuple[int, str]]: ...
