"""The simulated sensor's TRUE geometry, in physical terms, for the renderer.

This deliberately does not reuse the estimators' model (vision/): the laser plane at each mirror
angle is obtained by reflecting the projector's fan plane in the rotated mirror (Householder
reflection), and pixel rays are obtained by inverting the distortion with its own iteration.
Nothing here imports vision/: `app.sim.cell.true_sensor_model` hands the truth over to the
estimators' data types (tests, the demo).

Frame: the camera frame (OpenCV convention), which is also the sensor frame S.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import math
import os
import threading
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

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
        """Unit ray of every pixel centre, shape=(height, width, 3), read-only; distortion
        inverted by Newton's method on the forward model (`_rays`). The same camera's rays
        are computed once (`_rays_of`: 1.2 s of CPU, 30 MB)."""
        key = (self.fx_px, self.fy_px, self.cx_px, self.cy_px, *map(float, self.dist))
        return _rays_of((*key, float(self.width_px), float(self.height_px)))


@functools.lru_cache(maxsize=4)
def _rays_of(key: tuple[float, ...]) -> NDArray[np.float64]:
    """The pixel rays of the camera `key` (fx, fy, cx, cy, the 5 distortion coefficients,
    width, height), read-only: once a process, and once a machine in the user's cache folder
    (`_cache_file`; the same bits, np.save and np.load are exact), computed where it has none or
    cannot write there."""
    path = _cache_file(key)
    rays = None
    if path is not None:
        try:
            rays = np.load(path, allow_pickle=False)
        except (OSError, ValueError):
            rays = None
    if rays is None or rays.shape != (int(key[-1]), int(key[-2]), 3):
        rays = _rays(key)
        if path is not None:
            _save(path, rays)
    rays.flags.writeable = False
    return np.asarray(rays)


def _rays(key: tuple[float, ...]) -> NDArray[np.float64]:
    """Newton's method on the forward distortion (converged to < 1e-12 normalised units)."""
    fx, fy, cx, cy, *dist, width, height = key
    sensor = TrueSensor(fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy, dist=np.array(dist))
    v, u = np.mgrid[0 : int(height), 0 : int(width)].astype(np.float64)
    xd = (u - cx) / fx
    yd = (v - cy) / fy
    x, y = xd.copy(), yd.copy()
    eps = 1e-7
    for _ in range(6):
        fx_, fy_ = sensor._distort(x, y)
        ex, ey = fx_ - xd, fy_ - yd
        ax, ay = sensor._distort(x + eps, y)
        bx, by = sensor._distort(x, y + eps)
        j11, j21 = (ax - fx_) / eps, (ay - fy_) / eps
        j12, j22 = (bx - fx_) / eps, (by - fy_) / eps
        det = j11 * j22 - j12 * j21
        x -= (j22 * ex - j12 * ey) / det
        y -= (-j21 * ex + j11 * ey) / det
    rays = np.stack([x, y, np.ones_like(x)], axis=-1)
    return np.asarray(rays / np.linalg.norm(rays, axis=-1, keepdims=True))


#: the newest files the cache folder keeps
CACHE_FILES = 8


@functools.cache
def _computation() -> str | None:
    """The source of the rays' computation, `_rays` and `TrueSensor._distort`, read once a
    process (None where it cannot be read)."""
    try:
        return inspect.getsource(_rays) + inspect.getsource(TrueSensor._distort)
    except (OSError, TypeError):
        return None


def _cache_file(key: tuple[float, ...]) -> Path | None:
    """The camera's rays in `$XDG_CACHE_HOME/rvis` (default ~/.cache/rvis), named by the
    camera and the computation's source (a changed computation is not read from an older
    file); None without a home or a source."""
    source = _computation()
    try:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rvis"
    except RuntimeError:
        return None
    if source is None:
        return None
    digest = hashlib.sha256((repr(key) + source).encode()).hexdigest()[:20]
    return root / f"pixel-rays-{digest}.npy"


def _save(path: Path, rays: NDArray[np.float64]) -> None:
    """`rays` to `path` whole or not at all (a temporary file renamed), the folder kept to its
    CACHE_FILES newest; a folder it cannot write is no error (the next process computes)."""
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as f:
            np.save(f, rays, allow_pickle=False)
        os.replace(tmp, path)
        old = sorted(path.parent.glob("pixel-rays-*.npy"), key=lambda p: p.stat().st_mtime)
        for stale in old[:-CACHE_FILES]:
            stale.unlink(missing_ok=True)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)  # a full disk leaves no half file behind


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
