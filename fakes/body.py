"""The simulated bodies the line clamps: sheet-metal features built with a seeded process, and
what the laser-line sensor sees of them (the geometric path).

Each feature (a round hole, a slot, a surface point) sits on a flat patch of sheet wider than
the field of view. A body is built from the nominal (CAD, plain numbers: this module never reads
the feature plan's file) plus the body shop's build variation, `BuildProcess`:
- a per-feature mean offset (in the sheet's plane and along its normal; a few features built
  off-centre), a per-feature body-to-body spread, a slow drift over the bodies, and now and then
  a body with one feature far out (a worn pin, a bent flange);
- the diameter or slot size with its own mean offset and spread;
- a process shift of one feature's mean from a given body on (`shift`: a fixture or tool change
  at the body shop), for the SPC that tells process from gauge.
Body k is built from the seed and k alone, so it is the same body whatever was built before.

The truth (`TrueBody`) is what a CMM reports: the features in the body's own frame, which is the
part frame of a perfectly clamped body; each clamping puts the body off by the fixture's
repeatability (`clamp`), a small rigid move of the whole body, which the in-line measurement sees
and the CMM does not.

Geometric sensing (`feature_profiles`): for each laser plane of a sweep (the true sensor's), the
line where it cuts the sheet's top face in the sensor frame, sampled where each camera row sees
it, inside the field of view and off the feature's opening, from where the true robot stands,
with the sensor's noise along the camera's ray and across it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class NominalFeature:
    """A feature as designed (part frame, mm): kind "hole" | "slot" | "surface"; position_mm
    (3,) its centre on the sheet's top face; normal (3,) out of the sheet, towards the sensor;
    axis (3,) a slot's long axis (in the sheet's plane; ignored otherwise); size_mm: (d,) of a
    hole, (width, length) of a slot, () of a surface point; thickness_mm of the sheet."""

    id: str
    kind: str
    position_mm: F64
    normal: F64
    axis: F64
    size_mm: tuple[float, ...]
    thickness_mm: float = 0.8


@dataclass(frozen=True)
class TrueFeature:
    """A built feature in the body's frame (mm): position_mm (3,), unit normal (3,), unit
    axis (3,), size_mm as NominalFeature's."""

    id: str
    kind: str
    position_mm: F64
    normal: F64
    axis: F64
    size_mm: tuple[float, ...]


@dataclass(frozen=True)
class TrueBody:
    """Body `index`'s true features (what a CMM reports), by id."""

    index: int
    features: dict[str, TrueFeature]


@dataclass(frozen=True)
class BuildProcess:
    """The body shop's build variation [mm]. Per feature: a mean offset per in-plane axis and
    along the normal with sd `mean_sd_mm`, a share `off_centre_share` of the features built
    off-centre by `off_centre_mm`; a body-to-body sd drawn in `spread_mm` per feature; a drift
    of sd `drift_per_100_mm` per 100 bodies; the size's mean offset sd `size_mean_sd_mm` and
    body-to-body sd `size_sd_mm`; a share `out_share` of bodies with one feature moved by
    `out_mm` (a few bodies out of tolerance); the sheet's tilt sd `tilt_sd_rad`. shift:
    (feature id, first body, size [mm] along the normal and in-plane x) of a process shift."""

    seed: int = 0
    mean_sd_mm: float = 0.08
    off_centre_share: float = 0.15
    off_centre_mm: tuple[float, float] = (0.2, 0.3)
    spread_mm: tuple[float, float] = (0.1, 0.2)
    drift_per_100_mm: float = 0.05
    size_mean_sd_mm: float = 0.03
    size_sd_mm: float = 0.02
    out_share: float = 0.03
    out_mm: tuple[float, float] = (0.7, 1.0)
    tilt_sd_rad: float = 1e-3
    shift: tuple[str, int, float] | None = None


@dataclass(frozen=True)
class ClampSettings:
    """The fixture's repeatability: translation sd [mm] per axis, rotation sd [rad] per axis
    about the body's centroid."""

    translation_sd_mm: float = 0.01
    rotation_sd_rad: float = 5e-6


def _unit(v: F64) -> F64:
    return np.asarray(v / np.linalg.norm(v))


def _in_plane(normal: F64, axis: F64) -> tuple[F64, F64]:
    """Two unit vectors of the sheet's plane: the axis (projected) and normal x axis."""
    a = axis - (axis @ normal) * normal
    if np.linalg.norm(a) < 1e-9:
        ref = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        a = np.cross(normal, ref)
    a = _unit(a)
    return a, np.cross(normal, a)


@dataclass
class BodyShop:
    """Builds body k of a part type (`body`): deterministic in (process seed, k)."""

    nominal: Sequence[NominalFeature]
    process: BuildProcess = field(default_factory=BuildProcess)

    def __post_init__(self) -> None:
        p = self.process
        rng = np.random.default_rng([p.seed, 20])
        n = len(self.nominal)
        self._mean = rng.normal(0.0, p.mean_sd_mm, (n, 3))
        off = rng.random(n) < p.off_centre_share
        angle = rng.uniform(0, 2 * np.pi, n)
        size = rng.uniform(*p.off_centre_mm, n)
        self._mean[off, 0] = size[off] * np.cos(angle[off])
        self._mean[off, 1] = size[off] * np.sin(angle[off])
        self._spread = rng.uniform(*p.spread_mm, n)
        self._drift = rng.normal(0.0, p.drift_per_100_mm, (n, 3)) / 100.0
        self._size_mean = rng.normal(0.0, p.size_mean_sd_mm, (n, 2))

    def body(self, k: int) -> TrueBody:
        p = self.process
        rng = np.random.default_rng([p.seed, 21, k])
        n = len(self.nominal)
        dev = self._mean + self._drift * k + self._spread[:, None] * rng.normal(0.0, 1.0, (n, 3))
        size_dev = self._size_mean + rng.normal(0.0, p.size_sd_mm, (n, 2))
        tilt = rng.normal(0.0, p.tilt_sd_rad, (n, 2))
        if rng.random() < p.out_share:
            f = int(rng.integers(n))
            a = rng.uniform(0, 2 * np.pi)
            dev[f] += rng.uniform(*p.out_mm) * np.array([np.cos(a), np.sin(a), 0.0])
        out: dict[str, TrueFeature] = {}
        for i, nf in enumerate(self.nominal):
            d = dev[i].copy()
            if p.shift is not None and p.shift[0] == nf.id and k >= p.shift[1]:
                d += p.shift[2] * np.array([1.0, 0.0, 1.0])
            out[nf.id] = _built(nf, d, size_dev[i], tilt[i])
        return TrueBody(k, out)


def _built(nf: NominalFeature, dev: F64, size_dev: F64, tilt: F64) -> TrueFeature:
    """A feature moved by dev (in-plane along axis, across it, along the normal), its size by
    size_dev, its sheet tilted by tilt (rad about the two in-plane axes)."""
    n = _unit(np.asarray(nf.normal, float))
    a, b = _in_plane(n, np.asarray(nf.axis, float))
    if nf.kind == "surface":  # a surface point stays where it is in the plane: its sheet moves
        dev = np.array([0.0, 0.0, dev[2]])
    pos = nf.position_mm + dev[0] * a + dev[1] * b + dev[2] * n
    normal = _unit(n + tilt[0] * a + tilt[1] * b)
    axis, _ = _in_plane(normal, a)
    size = tuple(float(s + size_dev[j]) for j, s in enumerate(nf.size_mm))
    return TrueFeature(nf.id, nf.kind, pos, normal, axis, size)


def clamp(rng: np.random.Generator, body: TrueBody, s: ClampSettings | None = None) -> F64:
    """T_part_body (4, 4) of one clamping: the body off by the fixture's repeatability."""
    s = s or ClampSettings()
    centroid = np.mean([f.position_mm for f in body.features.values()], axis=0)
    w = rng.normal(0.0, s.rotation_sd_rad, 3)
    R = np.eye(3) + np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centroid - R @ centroid + rng.normal(0.0, s.translation_sd_mm, 3)
    return T


@dataclass(frozen=True)
class GeometricSensor:
    """What the geometric path needs of the true sensor (sensor frame = camera frame, mm):
    the camera's row geometry (fy, cy, rows), the field of view's half-width across the
    stripe at 1 mm depth (tan), the depth range it sees, and its noise per point along the
    camera's ray and across it."""

    fy_px: float
    cy_px: float
    rows: int
    half_tan_x: float
    z_range_mm: tuple[float, float] = (95.0, 145.0)
    noise_ray_mm: float = 0.02
    noise_across_mm: float = 0.004


def feature_profiles(
    feature: TrueFeature,
    T_part_body: F64,
    T_part_sensor: F64,
    planes: tuple[F64, F64],
    sensor: GeometricSensor,
    rng: np.random.Generator,
) -> list[F64]:
    """The stripe profiles (one (n_i, 3) per laser plane, ordered along the rows) in the
    sensor frame of the sheet around `feature`, clamped at T_part_body, seen from the true
    sensor pose T_part_sensor, laser planes (normals (k, 3), offsets (k,)) in the sensor
    frame."""
    T_sensor_body = np.linalg.inv(T_part_sensor) @ T_part_body
    R, t = T_sensor_body[:3, :3], T_sensor_body[:3, 3]
    c, m = R @ feature.position_mm + t, R @ feature.normal
    a = R @ feature.axis
    b = np.cross(m, a)
    ratio = (np.arange(sensor.rows) - sensor.cy_px) / sensor.fy_px
    normals, offsets = (np.asarray(v, float) for v in planes)
    if not len(offsets):
        return []
    # every plane at once: the line each laser plane cuts the sheet's plane in (direction u,
    # through x0, the least-norm solution of [n; m] X = [d, m.c]), where the camera's rows see it
    u = np.cross(normals, m)
    seen = np.linalg.norm(u, axis=1) >= 1e-9
    u[seen] /= np.linalg.norm(u[seen], axis=1, keepdims=True)
    nn, nm, mm = np.einsum("ij,ij->i", normals, normals), normals @ m, m @ m
    det = nn * mm - nm**2
    rhs = np.stack([offsets, np.full_like(offsets, m @ c)], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        w0 = (mm * rhs[:, 0] - nm * rhs[:, 1]) / det  # (A A^T)^-1 b, then x0 = A^T that
        w1 = (nn * rhs[:, 1] - nm * rhs[:, 0]) / det
        x0 = w0[:, None] * normals + w1[:, None] * m
        s = (ratio * x0[:, 2:3] - x0[:, 1:2]) / (u[:, 1:2] - ratio * u[:, 2:3])
        # each coordinate and the sheet's in-plane ones along the rows, (planes, rows) each
        x, z = x0[:, 0:1] + s * u[:, 0:1], x0[:, 2:3] + s * u[:, 2:3]
        keep = seen[:, None] & np.isfinite(z) & (z > sensor.z_range_mm[0])
        keep &= z < sensor.z_range_mm[1]
        keep &= np.abs(x) <= sensor.half_tan_x * np.where(keep, z, 1.0)
        rel0 = x0 - c
        along = (rel0 @ a)[:, None] + s * (u @ a)[:, None]
        across = (rel0 @ b)[:, None] + s * (u @ b)[:, None]
    keep &= ~_in_opening(feature, along, across)
    out: list[F64] = []
    for x0_i, u_i, s_i, keep_i, seen_i in zip(x0, u, s, keep, seen, strict=True):
        if not seen_i:
            out.append(np.zeros((0, 3)))
            continue
        X_i = x0_i + s_i[keep_i, None] * u_i
        out.append(X_i + _noise(rng, X_i, sensor))
    return out


def _in_opening(f: TrueFeature, along: F64, across: F64) -> NDArray[np.bool_]:
    if f.kind == "hole":
        out: NDArray[np.bool_] = along**2 + across**2 < (0.5 * f.size_mm[0]) ** 2
        return out
    if f.kind == "slot":
        w, length = f.size_mm
        half = max(0.5 * (length - w), 0.0)
        s = np.clip(along, -half, half)
        out = (along - s) ** 2 + across**2 < (0.5 * w) ** 2
        return out
    return np.zeros(np.shape(along), dtype=bool)


def _noise(rng: np.random.Generator, X: F64, sensor: GeometricSensor) -> F64:
    ray = X / np.linalg.norm(X, axis=1, keepdims=True)
    out: F64 = ray * rng.normal(0.0, sensor.noise_ray_mm, (len(X), 1))
    out += rng.normal(0.0, sensor.noise_across_mm, X.shape)
    return out
