"""Configurations that put a sphere in the sensor's view (paper section 4.2).

A sensor pose that sees a sphere centre p: the sensor's z axis (its view direction) never points
upward, and the sensor origin sits so that the centre appears at c_sensor (ideally
(0, 0, 130) mm: working distance 120 + radius 15 - half depth of field 5). The flange pose
follows from the pre-calibrated hand-eye and part->base pieces of the model, the joint angles
from the closed-form inverse kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import ik
from calib.model import SystemModel
from calib.transforms import apply, inverse, pose

F64 = NDArray[np.float64]

#: The ideal sphere-centre position in the sensor frame [mm] (paper: 120 + 15 - 5).
IDEAL_STANDOFF_MM = 130.0


def look_rotations(view_dir: ArrayLike, roll_rad: ArrayLike) -> F64:
    """Rotations (K, 3, 3) whose z axis is view_dir (K, 3) and whose x axis is turned by roll
    about it from the horizontal reference."""
    z = np.atleast_2d(np.asarray(view_dir, dtype=float))
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    ref = np.where(np.abs(z[:, 2:3]) < 0.99, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    x0 = np.cross(ref, z)
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    y0 = np.cross(z, x0)
    roll = np.asarray(roll_rad, dtype=float).reshape(-1, 1)
    x = np.cos(roll) * x0 + np.sin(roll) * y0
    y = np.cross(z, x)
    R: F64 = np.stack([x, y, z], axis=2)
    return R


def random_view_directions(rng: np.random.Generator, n: int, max_tilt_deg: float = 90.0) -> F64:
    """n unit view directions uniform over the downward cap within max_tilt_deg of straight
    down (z component <= 0: the sensor never looks upward)."""
    cos_max = np.cos(np.radians(max_tilt_deg))
    cz = rng.uniform(cos_max, 1.0, n)
    az = rng.uniform(-np.pi, np.pi, n)
    sz = np.sqrt(1.0 - cz**2)
    out: F64 = np.column_stack([sz * np.cos(az), sz * np.sin(az), -cz])
    return out


def flange_poses(
    model: SystemModel, x: F64, p_part_mm: ArrayLike, R_base_sensor: F64, c_sensor_mm: ArrayLike
) -> F64:
    """Flange poses T_base_flange (K, 4, 4) that put the sphere centre p_part_mm at
    c_sensor_mm (K, 3) in a sensor with orientation R_base_sensor (K, 3, 3)."""
    p_base = apply(inverse(model.T_part_base(x)), np.asarray(p_part_mm, dtype=float))
    c = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (R_base_sensor.shape[0], 3))
    origin = p_base - np.einsum("kij,kj->ki", R_base_sensor, c)
    T_base_sensor = pose(R_base_sensor, origin)
    out: F64 = T_base_sensor @ inverse(model.T_flange_sensor(x))
    return out


@dataclass(frozen=True)
class ViewSample:
    """Configurations (n, 6) [deg] and where the sphere should appear (n, 3) [mm]."""

    q_deg: F64
    c_planned_mm: F64


def random_configurations(
    model: SystemModel,
    x: F64,
    p_part_mm: ArrayLike,
    n: int,
    rng: np.random.Generator,
    *,
    max_offset_mm: tuple[float, float, float] = (10.0, 7.0, 2.0),
    max_tilt_deg: float = 75.0,
    max_tries: int = 200,
) -> ViewSample:
    """n random reachable configurations that see the sphere: random downward view, roll and
    offset in the field of view, one IK branch picked at random. Fewer when unreachable."""
    qs: list[F64] = []
    cs: list[F64] = []
    for _ in range(max_tries):
        if len(qs) >= n:
            break
        k = 4 * n
        views = random_view_directions(rng, k, max_tilt_deg)
        R = look_rotations(views, rng.uniform(-np.pi, np.pi, k))
        c = rng.uniform(-1.0, 1.0, (k, 3)) * np.asarray(max_offset_mm)
        c[:, 2] += IDEAL_STANDOFF_MM
        sols = ik.solve(flange_poses(model, x, p_part_mm, R, c), model.limits)
        for i in rng.permutation(k):
            options = sols.for_pose(int(i))
            if len(options) and len(qs) < n:
                qs.append(options[rng.integers(len(options))])
                cs.append(c[i])
    return ViewSample(np.array(qs).reshape(-1, 6), np.array(cs).reshape(-1, 3))
