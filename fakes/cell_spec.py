"""What the simulated cell is built from (fakes/cell.py): the cell as designed (`CellSpec`), the
sensor's measuring volume and the seeded error and noise settings (`SimSettings`); the
default cell's sphere positions, the paper's, are the cell file's (app/config/cell.py)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fakes.truth import M710IC50_RP_MM

F64 = NDArray[np.float64]


class NotVisible(Exception):
    """The sphere is outside the sensor's measuring volume from this configuration."""


@dataclass(frozen=True)
class MeasuringVolume:
    """Where a sphere centre must lie in the sensor frame to be measured [mm]: laterally
    inside the field of view, in depth within the depth of field around the ideal standoff."""

    half_x_mm: float = 18.5
    half_y_mm: float = 13.5
    z_min_mm: float = 125.0
    z_max_mm: float = 135.0

    def contains(self, c_sensor_mm: F64) -> NDArray[np.bool_]:
        c = np.atleast_2d(c_sensor_mm)
        inside: NDArray[np.bool_] = (
            (np.abs(c[:, 0]) <= self.half_x_mm)
            & (np.abs(c[:, 1]) <= self.half_y_mm)
            & (c[:, 2] >= self.z_min_mm)
            & (c[:, 2] <= self.z_max_mm)
        )
        return inside


@dataclass(frozen=True)
class CellSpec:
    """The nominal cell as designed: what the engineer believes (plain numbers, no model)."""

    T_part_base: F64
    T_flange_sensor: F64
    spheres_part_mm: Mapping[str, F64]
    sphere_radius_mm: float = 15.0
    volume: MeasuringVolume = field(default_factory=MeasuringVolume)


@dataclass(frozen=True)
class SimSettings:
    """Seeded error and noise settings of the simulated cell.

    repeatability_mm: the robot's pose repeatability, ISO 9283 RP [mm] (default the FANUC
    M-710iC/50 data sheet's +-0.07 mm; `fakes.truth.Repeatability` derives each stop's joint
    errors from it); 0 for a perfectly repeating robot, where a test needs an exact world.

    sensor_noise_mm: the geometric sensor's own noise, Gaussian per axis of the sensor frame
    [mm]. 5 um: a laser-line probe repeats a sphere centre to a few um (REFERENCE.md), the
    rendered path's vision to 1-2 um. Before the robot had its repeatability this was 20 um, a
    stand-in for sensor and robot together; the robot now brings 22 um RMS per axis at the
    sphere itself (15-34 um by view: 14-22 um at the flange, more at the standoff point through
    the flange's turn), and 20 um more from the sensor would count the robot twice (30 um per
    axis). With 5 um the geometric centre's non-repeatable error is 23 um per axis: the old
    stand-in's size, now with the robot's shape (a pose error, not isotropic noise)."""

    seed: int = 0
    tracker_noise_mm: float = 0.01
    sensor_noise_mm: float = 0.005
    repeatability_mm: float = M710IC50_RP_MM
    compliance: bool = True
    thermal: bool = True
    temp_c: float = 20.0
    base_error_mm: float = 1.0
    base_error_rad: float = 5e-4
    mount_error_mm: float = 0.5
    mount_error_rad: float = 2e-3
