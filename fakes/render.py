"""Physically based renderer of the laser-line sensor's images, with the truth it knows.

Ray casting through every pixel of the true camera (fakes.render_sensor.TrueSensor) onto a sphere
or a plane, lit by the true laser sheet at each mirror command: Gaussian sheet profile across the
plane, Lambertian shading toward the mirror, optional specular glint and a ghost (second
reflection); then speckle, blur, shot/read noise and quantisation (fakes.render_noise).

Public functions (all lengths mm in the sensor frame S = camera frame, commands in volts):

- render_sphere_sweep(c_sensor_mm, radius_mm, sensor, rng, ...) -> (frames, commands_v, truth)
- sphere_scene(sensor, c_sensor_mm, radius_mm) -> SphereScene (the laser-independent part of a
  sphere's rendering, to reuse across frames at one pose: `render_sphere_sweep(..., scene=)`)
- render_plane_sweep, render_chessboard: flat targets (fakes/render_plane.py)
- default_sweep_commands(n_frames)                                -> commands_v
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fakes.render_noise import (
    LIT_THRESHOLD,
    NoiseSettings,
    dark_frame,
    form_image_in_box,
    margin_px,
)
from fakes.render_sensor import TrueSensor

F64 = NDArray[np.float64]
Frames = NDArray[np.generic]


@dataclass(frozen=True)
class Lighting:
    """Laser and scene photometry: sheet_sigma_mm is the Gaussian sheet profile across the plane
    (1/e^2 half width = 2 sigma); power is the irradiance at normal incidence as a fraction of
    full well; glint_gain/glint_shininess a Phong specular lobe; ghost_gain/ghost_shift_px a
    shifted copy of the stripe (second reflection)."""

    sheet_sigma_mm: float = 0.05
    power: float = 0.35
    albedo: float = 1.0
    glint_gain: float = 0.0
    glint_shininess: float = 300.0
    ghost_gain: float = 0.0
    ghost_shift_px: int = 60


@dataclass(frozen=True, eq=False)
class SweepTruth:
    """What the renderer knows: the true laser planes per frame (n . X = d), the sphere (or the
    target plane) and, per frame, the true stripe centre line as a pixel polyline (u, v)."""

    commands_v: F64
    plane_normals: F64
    plane_offsets_mm: F64
    stripe_uv: list[F64] = field(default_factory=list)
    c_sensor_mm: F64 | None = None
    radius_mm: float | None = None
    target_normal: F64 | None = None
    target_offset_mm: float | None = None

    def stripe_columns(self, frame: int, rows: F64) -> F64:
        """True stripe column at the given rows of a frame (NaN where the stripe is absent)."""
        uv = self.stripe_uv[frame]
        if len(uv) < 2:
            return np.full(np.shape(rows), np.nan)
        order = np.argsort(uv[:, 1])
        return np.interp(rows, uv[order, 1], uv[order, 0], left=np.nan, right=np.nan)


def default_sweep_commands(n_frames: int = 60, span_v: float = 3.4) -> F64:
    """Mirror commands [V] that sweep the stripe across the field of view at 120-130 mm."""
    return np.linspace(-span_v, span_v, n_frames)


def _axis_foot(sensor: TrueSensor, X: F64) -> F64:
    """Closest points on the mirror axis to X shape=(n, 3): where the light comes from."""
    u = sensor.axis_dir / np.linalg.norm(sensor.axis_dir)
    p = sensor.axis_point_mm
    return np.asarray(p + np.outer((X - p) @ u, u))


def _surface_terms(sensor: TrueSensor, X: F64, N: F64, light: Lighting) -> tuple[F64, F64]:
    """Per surface point: Lambertian factor albedo*max(0, N.l) and the Phong glint factor."""
    to_light = _axis_foot(sensor, X) - X
    to_light /= np.linalg.norm(to_light, axis=1, keepdims=True)
    lam = light.albedo * np.clip(np.einsum("ij,ij->i", N, to_light), 0.0, None)
    glint = np.zeros(len(X))
    if light.glint_gain > 0:
        h = to_light - X / np.linalg.norm(X, axis=1, keepdims=True)
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        nh = np.clip(np.einsum("ij,ij->i", N, h), 0.0, None)
        glint = light.glint_gain * nh**light.glint_shininess * (lam > 0)
    return lam, glint


class _Tiles:
    """Surface points grouped by 16 x 16 pixel tiles, with each tile's bounding box [mm].
    `order`: the points' order by tile (stable: row by row within a tile)."""

    SIZE = 16

    def __init__(self, flat_idx: NDArray[np.intp], X: F64, width_px: int) -> None:
        self.order, t = _tile_order(flat_idx, width_px)
        self._bound(t, X[self.order])

    @classmethod
    def of_ordered(cls, tile_ids: NDArray[np.integer[Any]], Xs: F64) -> _Tiles:
        """The tiles of points already in tile order (`_tile_order`'s ids and points)."""
        tiles = cls.__new__(cls)
        tiles.order = np.arange(len(Xs))
        tiles._bound(tile_ids, Xs)
        return tiles

    def _bound(self, t: NDArray[np.integer[Any]], Xs: F64) -> None:
        self.starts = np.flatnonzero(np.r_[True, t[1:] != t[:-1]]) if t.size else np.zeros(0, int)
        self.ends = np.r_[self.starts[1:], t.size].astype(np.intp)
        self.lo = np.minimum.reduceat(Xs, self.starts, axis=0) if t.size else np.zeros((0, 3))
        self.hi = np.maximum.reduceat(Xs, self.starts, axis=0) if t.size else np.zeros((0, 3))

    def candidates(self, n: F64, d: float, cut: float) -> NDArray[np.intp]:
        """Indices (into the tile-ordered points) of every tile that may hold points within
        `cut` of the plane n . X = d."""
        s_min = np.where(n > 0, self.lo * n, self.hi * n).sum(axis=1) - d
        s_max = np.where(n > 0, self.hi * n, self.lo * n).sum(axis=1) - d
        hit = np.flatnonzero((s_min < cut + 1e-9) & (s_max > -cut - 1e-9))
        if hit.size == 0:
            return np.zeros(0, dtype=np.intp)
        lengths = self.ends[hit] - self.starts[hit]
        shift = np.repeat(self.starts[hit] - np.r_[0, np.cumsum(lengths)[:-1]], lengths)
        return np.asarray(np.arange(int(lengths.sum())) + shift, dtype=np.intp)


def _tile_order(
    flat_idx: NDArray[np.intp], width_px: int
) -> tuple[NDArray[np.intp], NDArray[np.integer[Any]]]:
    """The pixels' order by 16 x 16 tile (stable) and their tile ids in that order."""
    size = _Tiles.SIZE
    rows, cols = np.divmod(flat_idx, width_px)
    per_row = -(-width_px // size)
    tid = (rows // size) * per_row + cols // size
    if tid.size and tid.max() < 65536:
        tid = tid.astype(np.uint16)  # radix sort
    order = np.argsort(tid, kind="stable")
    return order, tid[order]


def render_frames(
    sensor: TrueSensor,
    flat_idx: NDArray[np.intp],
    X: F64,
    N: F64,
    normals: F64,
    offsets: F64,
    light: Lighting,
    noise: NoiseSettings,
    rng: np.random.Generator,
    cull: bool = True,
    tiles: _Tiles | None = None,
) -> Frames:
    """Frames for surface points X (visible at pixels flat_idx) under each laser plane.

    Only the points within 5 sheet sigmas of a frame's plane are shaded; they are found tile by
    tile (16 x 16 pixels: a tile whose points' bounding box lies farther from the plane is
    skipped, exactly, since the distance is linear). The image formation runs in full inside
    their bounding box (plus the speckle/blur margin and the ghost's shift), the rest of the
    frame is dark (`form_image_in_box`). `tiles`: the points come already ordered by these tiles
    (a SphereScene's)."""
    h, w = sensor.height_px, sensor.width_px
    if tiles is None and cull:
        tiles = _Tiles(flat_idx, X, w)
        flat_idx, X, N = flat_idx[tiles.order], X[tiles.order], N[tiles.order]
    rows, cols = np.divmod(flat_idx, w)
    cut = 5.0 * light.sheet_sigma_mm
    margin = margin_px(noise)
    ghost = light.ghost_shift_px if light.ghost_gain > 0 else 0
    frames = []
    for n, d in zip(normals, offsets, strict=True):
        if tiles is None:
            s = X @ n - d
            near = np.flatnonzero(np.abs(s) < cut)
        else:
            cand = tiles.candidates(n, float(d), cut)
            s_c = X[cand] @ n - d
            keep = np.abs(s_c) < cut
            near, s = cand[keep], np.zeros(len(X))
            s[near] = s_c[keep]
        lam, glint = _surface_terms(sensor, X[near], N[near], light)
        irr = light.power * (lam + glint) * np.exp(-0.5 * (s[near] / light.sheet_sigma_mm) ** 2)
        lit = irr > LIT_THRESHOLD
        if not np.any(lit):
            frames.append(dark_frame((h, w), noise, rng))
            continue
        r, c = rows[near], cols[near]
        r0, r1 = max(int(r[lit].min()) - margin, 0), min(int(r[lit].max()) + margin + 1, h)
        c0 = max(int(c[lit].min()) - margin, 0)
        c1 = min(int(c[lit].max()) + margin + ghost + 1, w)
        inside = (r >= r0) & (r < r1) & (c >= c0) & (c < c1)
        crop = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
        crop[r[inside] - r0, c[inside] - c0] = irr[inside]
        if ghost and ghost < crop.shape[1]:
            crop[:, ghost:] += np.float32(light.ghost_gain) * crop[:, :-ghost].copy()
        frames.append(form_image_in_box((h, w), (slice(r0, r1), slice(c0, c1)), crop, noise, rng))
    return np.stack(frames)


def _sphere_box(sensor: TrueSensor, c: F64, r: float) -> tuple[slice, slice]:
    """Pixel box (rows, columns) that holds the sphere's image: its silhouette (the circle
    where the viewing cone touches the sphere) projected, plus 4 pixels; the whole frame when
    the silhouette reaches behind the camera."""
    h, w = sensor.height_px, sensor.width_px
    dist = float(np.linalg.norm(c))
    if dist <= r * 1.0001:
        return slice(0, h), slice(0, w)
    k = c / dist
    centre = c * (1.0 - (r / dist) ** 2)
    rho = r * np.sqrt(1.0 - (r / dist) ** 2)
    e1 = np.cross(k, [1.0, 0.0, 0.0] if abs(k[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(k, e1)
    phi = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    P = centre + rho * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    if np.min(P[:, 2]) <= 1e-3 * dist:
        return slice(0, h), slice(0, w)
    uv = sensor.project(P)
    u0, u1 = int(np.floor(uv[:, 0].min())) - 4, int(np.ceil(uv[:, 0].max())) + 5
    v0, v1 = int(np.floor(uv[:, 1].min())) - 4, int(np.ceil(uv[:, 1].max())) + 5
    return slice(min(max(v0, 0), h), min(max(v1, 0), h)), slice(
        min(max(u0, 0), w), min(max(u1, 0), w)
    )


def sphere_hits(
    sensor: TrueSensor, c_sensor_mm: F64, radius_mm: float, *, roi: bool = True
) -> tuple[NDArray[np.intp], F64]:
    """Pixels that see the sphere (flat indices into the frame) and the surface points they
    see [mm]; with roi, rays are cast only inside the sphere's image box (`_sphere_box`)."""
    flat_idx, rays, local, t = _sphere_rays(sensor, c_sensor_mm, radius_mm, roi)
    return flat_idx, rays[local] * t[:, None]


def _sphere_rays(
    sensor: TrueSensor, c_sensor_mm: F64, radius_mm: float, roi: bool = True
) -> tuple[NDArray[np.intp], F64, NDArray[np.intp], F64]:
    """`sphere_hits` before its points: the pixels' flat indices, the rays cast (n, 3), which
    of them hit (`local`) and their distance to the hit [mm] (X = rays[local] * t)."""
    c = np.asarray(c_sensor_mm, dtype=np.float64)
    h, w = sensor.height_px, sensor.width_px
    rs, cs = _sphere_box(sensor, c, radius_mm) if roi else (slice(0, h), slice(0, w))
    rays = sensor.pixel_rays[rs, cs].reshape(-1, 3)
    b = rays @ c
    disc = b * b - (c @ c - radius_mm**2)
    local = np.flatnonzero(disc > 0)
    t = b[local] - np.sqrt(disc[local])
    bw = cs.stop - cs.start
    flat_idx = (rs.start + local // bw) * w + cs.start + local % bw
    return flat_idx, rays, local, t


def _circle_polyline(
    sensor: TrueSensor, c: F64, r: float, n: F64, d: float, facing: bool = True
) -> F64:
    """True stripe centre line: plane-sphere circle, visible and lit part, projected (m, 2)."""
    P = _visible_arc(sensor, c, r, n, d)
    return np.asarray(sensor.project(P)) if len(P) else np.zeros((0, 2))


def _visible_arc(
    sensor: TrueSensor, c: F64, r: float, n: F64, d: float, n_points: int = 20000
) -> F64:
    """The plane-sphere circle's part that the camera sees and the laser lights: surface points
    (m, 3) [mm] of n_points around the circle, contiguous along the circle."""
    dist = float(n @ c - d)
    if abs(dist) >= r:
        return np.zeros((0, 3))
    q = c - dist * n
    rho = np.sqrt(r * r - dist * dist)
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    phi = np.linspace(0.0, 2 * np.pi, n_points, endpoint=False)
    P = q + rho * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    Nrm = (P - c) / r
    keep = np.einsum("ij,ij->i", Nrm, -P) > 0
    keep &= np.einsum("ij,ij->i", Nrm, _axis_foot(sensor, P) - P) > 0
    if not np.any(keep):
        return np.zeros((0, 3))
    # start the arc at a hidden point so the visible part is contiguous
    start = int(np.argmin(keep)) if not np.all(keep) else 0
    P, keep = np.roll(P, -start, axis=0), np.roll(keep, -start)
    return np.asarray(P[keep])


@dataclass(frozen=True, eq=False)
class StripeRows:
    """The noise-free stripe of one frame as a row-wise extractor reports it: one point per image
    row that the visible, lit stripe crosses exactly once (rows it crosses twice are left out,
    as an extractor rejects a row with two peaks); u_px, v_px shape=(n,) (v_px integer rows),
    and the Lambertian factor of the surface there (how bright the stripe is, 0..1)."""

    u_px: F64
    v_px: F64
    lambert: F64


def stripe_rows(
    sensor: TrueSensor, c_sensor_mm: F64, radius_mm: float, commands_v: F64
) -> list[StripeRows]:
    """The true sensor's observation of a sphere without an image: for each mirror command, the
    plane-sphere circle's visible and lit arc projected by the true camera, sampled at the image
    rows. What a perfect stripe extractor would hand to triangulation (no speckle, no noise)."""
    c = np.asarray(c_sensor_mm, dtype=np.float64)
    normals, offsets = sensor.laser_planes(np.asarray(commands_v, dtype=np.float64))
    out = []
    for n, d in zip(normals, offsets, strict=True):
        P = _visible_arc(sensor, c, radius_mm, n, float(d), n_points=4000)
        out.append(_rows_of_arc(sensor, c, radius_mm, P))
    return out


def _rows_of_arc(sensor: TrueSensor, c: F64, r: float, P: F64) -> StripeRows:
    """Sample an arc of surface points P (m, 3), ordered along the arc, at integer image rows."""
    empty = StripeRows(np.zeros(0), np.zeros(0), np.zeros(0))
    if len(P) < 2:
        return empty
    uv = sensor.project(P)
    k = np.floor(uv[:, 1])
    seg = np.flatnonzero(k[1:] != k[:-1])
    if seg.size == 0:
        return empty
    row = np.maximum(k[seg], k[seg + 1])
    t = (row - uv[seg, 1]) / (uv[seg + 1, 1] - uv[seg, 1])
    u = uv[seg, 0] + t * (uv[seg + 1, 0] - uv[seg, 0])
    X = P[seg] + t[:, None] * (P[seg + 1] - P[seg])
    lam, _ = _surface_terms(sensor, X, (X - c) / r, Lighting())
    rows, counts = np.unique(row, return_counts=True)
    once = np.isin(row, rows[counts == 1])
    once &= (row >= 0) & (row < sensor.height_px) & (u >= 0) & (u <= sensor.width_px - 1)
    order = np.argsort(row[once])
    return StripeRows(u[once][order], row[once][order], lam[once][order])


@dataclass(frozen=True, eq=False)
class SphereScene:
    """What the camera sees of one sphere, whatever the laser does: the pixels that see it
    (flat indices), their surface points X and normals N (ordered by 16 x 16 pixel tiles) and
    the tiles. The costly, laser-independent part of rendering a frame."""

    c_sensor_mm: F64
    radius_mm: float
    flat_idx: NDArray[np.intp]
    X: F64
    N: F64
    tiles: _Tiles


def sphere_scene(sensor: TrueSensor, c_sensor_mm: F64, radius_mm: float) -> SphereScene:
    """The scene of the sphere of centre c_sensor_mm (3,) [mm] in S and radius radius_mm."""
    c = np.array(c_sensor_mm, dtype=np.float64)
    flat_idx, rays, local, t = _sphere_rays(sensor, c, radius_mm)
    order, tile_ids = _tile_order(flat_idx, sensor.width_px)
    # the points gathered in tile order at once (the same values as sphere_hits's, reordered)
    X = np.take(rays, local[order], axis=0) * t[order][:, None]
    N = (X - c) / radius_mm
    tiles = _Tiles.of_ordered(tile_ids, X)
    return SphereScene(c, float(radius_mm), flat_idx[order], X, N, tiles)


def render_sphere_sweep(
    c_sensor_mm: F64,
    radius_mm: float,
    sensor: TrueSensor,
    rng: np.random.Generator,
    *,
    commands_v: F64 | None = None,
    noise: NoiseSettings | None = None,
    light: Lighting | None = None,
    angle_noise_rad: float = 0.0,
    stripe_truth: bool = True,
    scene: SphereScene | None = None,
) -> tuple[Frames, F64, SweepTruth]:
    """Render one galvo sweep over a sphere.

    c_sensor_mm: true sphere centre shape=(3,) [mm] in S; radius_mm: true radius; sensor: true
    geometry; rng: the only source of randomness; commands_v: mirror commands shape=(n,) [V]
    (default `default_sweep_commands()`); angle_noise_rad: mirror angle repeatability (RMS,
    added to the true angle of each frame, the commands returned are the nominal ones);
    stripe_truth: compute the true stripe polylines (False leaves truth.stripe_uv empty, which
    saves a few ms per frame when only the centre matters); scene: `sphere_scene` of this very
    sphere, computed once for several renders at one pose (the frames are the same as without).
    Returns frames shape=(n, H, W) uint8 (uint16 for 12 bit), the commands, and the truth.
    """
    noise = noise or NoiseSettings()
    light = light or Lighting()
    cmds = default_sweep_commands() if commands_v is None else np.asarray(commands_v, float)
    c = np.asarray(c_sensor_mm, dtype=np.float64)
    if scene is None:
        scene = sphere_scene(sensor, c, radius_mm)
    elif scene.radius_mm != radius_mm or not np.array_equal(scene.c_sensor_mm, c):
        raise ValueError("the scene is of another sphere")
    jitter = angle_noise_rad * rng.standard_normal(len(cmds))
    normals, offsets = _planes_with_jitter(sensor, cmds, jitter)
    frames = render_frames(
        sensor,
        scene.flat_idx,
        scene.X,
        scene.N,
        normals,
        offsets,
        light,
        noise,
        rng,
        tiles=scene.tiles,
    )
    stripes = (
        [
            _circle_polyline(sensor, c, radius_mm, n, d)
            for n, d in zip(normals, offsets, strict=True)
        ]
        if stripe_truth
        else []
    )
    truth = SweepTruth(
        commands_v=cmds,
        plane_normals=normals,
        plane_offsets_mm=offsets,
        stripe_uv=stripes,
        c_sensor_mm=c,
        radius_mm=radius_mm,
    )
    return frames, cmds, truth


def _planes_with_jitter(sensor: TrueSensor, cmds: F64, jitter: F64) -> tuple[F64, F64]:
    """True planes for commands, the mirror angle perturbed by `jitter` [rad] per frame."""
    if not np.any(jitter):
        return sensor.laser_planes(cmds)
    # a mirror-angle error equals a command error of jitter / (d theta / d command)
    slope = np.polynomial.polynomial.polyval(
        cmds, np.polynomial.polynomial.polyder(sensor.angle_poly_rad)
    )
    return sensor.laser_planes(cmds + jitter / slope)
