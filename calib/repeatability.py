"""The robot's pose repeatability (ISO 9283 RP) as the estimators see it: the joint errors of a
stop that give the data sheet's figure, and what they do to a reference that the robot's own
motion provides (the sensor acceptance's sphere-spacing error SD, app/commission/acceptance.py).

ISO 9283's RP is mean + 3 std of the distance l of the attained positions from their barycentre.
For an isotropic Gaussian error of sigma per axis, l / sigma follows the chi distribution with 3
degrees of freedom (mean 2 sqrt(2 / pi), std sqrt(3 - 8 / pi)), so RP = 3.616 sigma. The
non-repeatable error is modelled at the joints: every physical joint angle
(J3 not coupled to J2) off by an independent Gaussian error of one sigma, drawn anew at every
stop, the sigma chosen so that the flange's attained positions at the cell's home (the middle of
the working range, where ISO 9283 puts its test cube) have the data sheet's RP. The simulated
world (fakes/truth.py, which may not import this package) models its true robot the same way.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import datasheet, robot
from calib.model import SystemModel

F64 = NDArray[np.float64]


def controller_offsets_deg(dtheta_rad: ArrayLike) -> F64:
    """Controller-angle offsets (..., 6) [deg] of physical joint offsets (..., 6) [rad]."""
    q_deg: F64 = np.degrees(np.asarray(dtheta_rad, dtype=float) @ robot.COUPLING_INV.T)
    return q_deg


def joint_sigma_rad(model: SystemModel, x: F64, rp_mm: float, *, draws: int = 20_000) -> float:
    """The standard deviation [rad] of each physical joint's error at a stop that gives the
    flange the pose repeatability rp_mm [mm] at the cell's home (module docstring), through the
    model's flange position Jacobian (central differences; the errors are small, so linear) and
    ISO 9283's RP on `draws` seeded stops."""
    if not (math.isfinite(rp_mm) and rp_mm >= 0):
        raise ValueError(f"pose repeatability {rp_mm!r} mm must be >= 0")
    if rp_mm == 0:
        return 0.0
    q = np.asarray(datasheet.HOME_DEG, dtype=float)
    h = 1e-6
    dq = controller_offsets_deg(np.vstack([h * np.eye(6), -h * np.eye(6)]))
    p = model.fk(x, q + dq, flange=True)[:, :3, 3]
    J = (p[:6] - p[6:]).T / (2 * h)
    e = np.random.default_rng(9283).normal(0.0, 1.0, (draws, 6)) @ J.T
    distance = np.linalg.norm(e - e.mean(axis=0), axis=1)
    return float(rp_mm / (distance.mean() + 3.0 * distance.std()))


def stop_errors_deg(rng: np.random.Generator, sigma_rad: float, shape: tuple[int, ...]) -> F64:
    """Controller-angle errors (*shape, 6) [deg] of stops with physical joint sigma_rad."""
    return controller_offsets_deg(rng.normal(0.0, sigma_rad, (*shape, 6)))
