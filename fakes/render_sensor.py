"""The simulated sensor's TRUE geometry, in physical terms, for the renderer.

This deliberately does not reuse the estimators' model (vision/): the laser plane at each mirror
angle is obtained by reflecting the projector's fan plane in the rotated mirror (Householder
reflection), and pixel rays are obtained by inverting the distortion with its own iteration.
Nothing here imports vision/: `app.sim.cell.true_sensor_model` hands the truth over to the
estimators' data types (tests, the demo).

Frame: the camera frame (OpenCV convention), which is also the sensor frame S.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def _unit(v: F64) -> F64:
    return np.asarray(v / np.linalg.norm(v))


def _rodrigues(v: F64, k: F64, angle: F64) -> F64:
    """Rotate v shape=(3,) about unit k by angles shape=(n,): shape=(n, 3)."""
    a = angle[:, None]
    return np.asarray(v * np.cos(a) + np.cross(k, v) * np.sin(a) + k * (k @ v) * (1 - np.cos(a)))


@dataclass
class TrueSensor:
    """True camera and galvo geometry [mm, rad, px], camera frame.

    The projector's fan travels along `fan_dir` and hits the mirror along the mirror axis; the
    mirror normal at angle 0 is `mirror_normal0`; `mirror_offset_mm` moves the mirror surface off
    the rotation axis (0 = the estimators' model is exact). Mirror angle = polyval(command,
    angle_poly_rad) + its own small command-independent `angle_jitter_rad` handled by the renderer.
    """

    fx_px: float = 16.0 / 0.00375
    fy_px: float = 16.0 / 0.00375
    cx_px: float = 647.5
    cy_px: float = 482.5
    dist: F64 = field(default_factory=lambda: np.array([-0.08, 0.15, 1e-4, -1e-4, 0.0]))
    width_px: int = 1296
    height_px: int = 966
    axis_point_mm: F64 = field(default_factory=lambda: np.array([70.0, 0.0, 0.0]))
    axis_dir: F64 = field(default_factory=lambda: _unit(np.array([0.0, 1.0, 0.01])))
    fan_dir: F64 = field(default_factory=lambda: np.array([-1.0, 0.0, 0.0]))
    out_dir0: F64 = field(
        default_factory=lambda: np.array(
            [-math.sin(math.radians(30)), 0.0, math.cos(math.radians(30))]
        )
    )
    mirror_offset_mm: float = 0.0
    angle_poly_rad: F64 = field(default_factory=lambda: np.radians([0.0, 1.0, 0.004, 0.0]))

    @property
    def mirror_normal0(self) -> F64:
        """Mirror normal at angle 0: bisects the fan's incoming and outgoing directions."""
        u = _unit(self.axis_dir)
        d_in = _unit(self.fan_dir - u * (u @ self.fan_dir))
        d_out = _unit(self.out_dir0 - u * (u @ self.out_dir0))
        return _unit(d_out - d_in)

    def laser_planes(self, command_v: F64) -> tuple[F64, F64]:
        """True laser planes for commands [V]: normals shape=(n, 3), offsets shape=(n,) [mm]."""
        u = _unit(self.axis_dir)
        cmd = np.atleast_1d(np.asarray(command_v, dtype=np.float64))
        theta = np.asarray(np.polynomial.polynomial.polyval(cmd, self.angle_poly_rad), np.float64)
        m = _rodrigues(self.mirror_normal0, u, theta)
        n_in = _unit(np.cross(u, self.fan_dir))
        d_in = float(n_in @ self.axis_point_mm)
        e = m @ self.axis_point_mm + self.mirror_offset_mm
        mn = m @ n_in
        n_out = n_in - 2.0 * mn[:, None] * m
        d_out = d_in - 2.0 * e * mn
        return n_out, d_out

    def project(self, X_mm: F64) -> F64:
        """Project points shape=(..., 3) [mm] to distorted pixels shape=(..., 2)."""
        x = X_mm[..., 0] / X_mm[..., 2]
        y = X_mm[..., 1] / X_mm[..., 2]
        xd, yd = self._distort(x, y)
        return np.stack([self.fx_px * xd + self.cx_px, self.fy_px * yd + self.cy_px], axis=-1)

    def _distort(self, x: F64, y: F64) -> tuple[F64, F64]:
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    @cached_property
    def pixel_rays(self) -> NDArray[np.float64]:
        """Unit ray of every pixel centre, shape=(height, width, 3); distortion inverted by
        Newton's method on the forward model (converged to < 1e-12 normalised units)."""
        v, u = np.mgrid[0 : self.height_px, 0 : self.width_px].astype(np.float64)
        xd = (u - self.cx_px) / self.fx_px
        yd = (v - self.cy_px) / self.fy_px
        x, y = xd.copy(), yd.copy()
        eps = 1e-7
        for _ in range(6):
            fx, fy = self._distort(x, y)
            ex, ey = fx - xd, fy - yd
            ax, ay = self._distort(x + eps, y)
            bx, by = self._distort(x, y + eps)
            j11, j21 = (ax - fx) / eps, (ay - fy) / eps
            j12, j22 = (bx - fx) / eps, (by - fy) / eps
            det = j11 * j22 - j12 * j21
            x -= (j22 * ex - j12 * ey) / det
            y -= (-j21 * ex + j11 * ey) / det
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        return np.asarray(rays / np.linalg.norm(rays, axis=-1, keepdims=True))


def default_true_sensor() -> TrueSensor:
    """The simulated sensor as built (matches vision.sensor_model.default_sensor_model)."""
    return TrueSensor()


def replaced_sensor(sensor: TrueSensor, rng: np.random.Generator) -> TrueSensor:
    """Another sensor of the same type (a sensor replaced, fakes.truth.Maintenance): its own
    lens and assembly within the type's tolerances: focal lengths +-0.5 %, principal point
    +-8 px, distortion +-10 %, the mirror's axis 0.5 mm and 0.2 deg off, its angle's zero
    0.1 deg off. The calibration of the sensor it replaces is wrong for it."""
    from dataclasses import replace

    f = 1.0 + rng.uniform(-0.005, 0.005, 2)
    axis = _unit(sensor.axis_dir + rng.normal(0.0, math.radians(0.2) / math.sqrt(3.0), 3))
    poly = sensor.angle_poly_rad.copy()
    poly[0] += math.radians(rng.uniform(-0.1, 0.1))
    return replace(
        sensor,
        fx_px=sensor.fx_px * float(f[0]),
        fy_px=sensor.fy_px * float(f[1]),
        cx_px=sensor.cx_px + float(rng.uniform(-8.0, 8.0)),
        cy_px=sensor.cy_px + float(rng.uniform(-8.0, 8.0)),
        dist=sensor.dist * (1.0 + rng.uniform(-0.1, 0.1, 5)),
        axis_point_mm=sensor.axis_point_mm + rng.normal(0.0, 0.5 / math.sqrt(3.0), 3),
        axis_dir=axis,
        angle_poly_rad=poly,
    )
