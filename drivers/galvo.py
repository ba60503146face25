"""The galvanometer family: the laser sweep is commanded in DAC volts.

One source of truth for the command model: the driver knows volts and volt limits only. How a
command [V] turns into the laser plane is the sensor's calibration (the sensor file's
``angle_poly_deg``, vision/sensor_model.py, format rvis-sensor/1, maps volts to the laser-plane
angle), which the vision pipeline applies; the drivers never import it.

Backend primitives: ``_identify()``, ``_set_volts(v)``, ``_get_volts()``, ``_errors() ->
list[(code, message)]`` (the DAC's error queue). Policy here: the volt limits (MotionRefused,
nothing sent), error-queue check after every set, retry after a reconnect (setting a voltage is
idempotent).
"""

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import dataclass

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceFault, MotionRefused


@dataclass(frozen=True)
class GalvoSettings:
    """The command range [V] the galvo accepts: inside the DAC's range and the mirror's
    mechanical travel (cell file ``[galvo]`` ``volt_min``, ``volt_max``)."""

    volt_min: float = -10.0
    volt_max: float = 10.0

    def __post_init__(self) -> None:
        finite = math.isfinite(self.volt_min) and math.isfinite(self.volt_max)
        if not (finite and self.volt_min < self.volt_max):
            raise DeviceConfigError(
                f"galvo volt limits need volt_min < volt_max, got {self.volt_min}, {self.volt_max}"
            )


class Galvo(Device):
    """A one-mirror galvanometer commanded by a DAC voltage [V]."""

    family = "galvo"

    def __init__(
        self, *, settings: GalvoSettings | None = None, timeout_s: float = 1.0, name: str = ""
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        self.settings = settings or GalvoSettings()

    def describe(self) -> str:
        return self._read_retrying(self._identify)

    def set_volts(self, command_v: float) -> float:
        """Command the mirror [V]; returns the voltage sent. MotionRefused outside the limits
        (nothing sent); DeviceFault when the DAC reports an error."""
        self._check_open()
        lo, hi = self.settings.volt_min, self.settings.volt_max
        if not (math.isfinite(command_v) and lo <= command_v <= hi):
            raise MotionRefused(f"galvo command {command_v} V outside [{lo}, {hi}] V")
        volts = float(command_v)

        def _set() -> None:
            self._set_volts(volts)
            self._raise_errors()

        self._read_retrying(_set)  # idempotent: safe to repeat after a reconnect
        return volts

    def volts(self) -> float:
        """The command [V] the DAC is outputting now (read back from the device)."""
        return float(self._read_retrying(self._get_volts))

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
