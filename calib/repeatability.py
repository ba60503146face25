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

import functools
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import datasheet, robot
from calib.model import SystemModel

F64 = NDArray[np.float64]

#: the physical joints' offsets: a stop's joint errors enter the model as these do
JOINT_OFFSETS = tuple(f"dtheta{i}" for i in range(1, 7))


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
    e = _unit_draws(draws) @ J.T
    distance = np.linalg.norm(e - e.mean(axis=0), axis=1)
    return float(rp_mm / (distance.mean() + 3.0 * distance.std()))


def stop_sd_mm(
    model: SystemModel, x: F64, q_deg: ArrayLike, p_part_mm: ArrayLike, rp_mm: float
) -> float:
    """One coordinate's standard deviation [mm] of points fixed in the part frame, p_part_mm
    (n, 3), each measured from a stop of its own at q_deg (n, 6) by a robot whose pose
    repeatability is the data sheet's RP rp_mm (joint_sigma_rad at every physical joint): the
    root of the mean over the n views of sigma^2 trace(J J') / 3, J the point's Jacobian in
    the joints' offsets. 0 for an exact robot or no view."""
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    if rp_mm == 0 or q.size == 0:
        return 0.0
    sigma = joint_sigma_rad(model, x, rp_mm)
    c = model.points_sensor(x, q, p_part_mm)
    J = model.point_jacobian(x, q, c, JOINT_OFFSETS)  # (n, 3, 6)
    return float(sigma * math.sqrt(float(np.mean(np.sum(J**2, axis=(1, 2)))) / 3.0))


@functools.lru_cache(maxsize=4)
def _unit_draws(draws: int) -> F64:
    """The seeded standard-normal joint errors (draws, 6) of joint_sigma_rad, drawn once (read
    only: every call sees the same stops)."""
    z = np.random.default_rng(9283).normal(0.0, 1.0, (draws, 6))
    z.flags.writeable = False
    return z


def stop_errors_deg(rng: np.random.Generator, sigma_rad: float, shape: tuple[int, ...]) -> F64:
    """Controller-angle errors (*shape, 6) [deg] of stops with physical joint sigma_rad."""
    return controller_offsets_deg(rng.normal(0.0, sigma_rad, (*shape, 6)))
