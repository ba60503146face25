"""Flat calibration targets rendered with their truth (fakes/render.py's ray casting onto a
plane): a white plate swept by the laser, and a chessboard under ambient light.

- render_plane_sweep(T_camera_target, sensor, rng, ...) -> (frames, commands_v, truth)
- render_chessboard(T_camera_target, sensor, rng, ...)  -> (frame, corners_px, object_mm)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fakes.render import Frames, Lighting, SweepTruth, default_sweep_commands, render_frames
from fakes.render_noise import NoiseSettings, form_image
from fakes.render_sensor import TrueSensor

F64 = NDArray[np.float64]


def _plane_hits(sensor: TrueSensor, T_camera_target: F64) -> tuple[NDArray[np.intp], F64, F64, F64]:
    """Pixels seeing the target plane (z = 0 of the target), their points and distances."""
    n = T_camera_target[:3, 2]
    p0 = T_camera_target[:3, 3]
    rays = sensor.pixel_rays.reshape(-1, 3)
    denom = rays @ n
    t = (p0 @ n) / np.where(np.abs(denom) > 1e-9, denom, np.nan)
    hit = t > 0
    if hit.all():  # the plane fills the frame (a target): no gather
        return np.arange(len(t)), rays * t[:, None], t, denom
    flat_idx = np.flatnonzero(hit)
    X = rays[flat_idx] * t[flat_idx, None]
    return flat_idx, X, t[flat_idx], denom[flat_idx]


def render_plane_sweep(
    T_camera_target: F64,
    sensor: TrueSensor,
    rng: np.random.Generator,
    *,
    commands_v: F64 | None = None,
    noise: NoiseSettings | None = None,
    light: Lighting | None = None,
) -> tuple[Frames, F64, SweepTruth]:
    """Render a galvo sweep over a flat, uniformly white calibration target.

    T_camera_target: 4x4 pose of the target (its plane is the target's z = 0) in the camera
    frame. Returns frames shape=(n, H, W), the commands [V] and the truth (planes, stripe lines).
    """
    noise = noise or NoiseSettings()
    light = light or Lighting(albedo=0.8)
    cmds = default_sweep_commands() if commands_v is None else np.asarray(commands_v, float)
    flat_idx, X, _, _ = _plane_hits(sensor, T_camera_target)
    n_t = T_camera_target[:3, 2]
    N = np.broadcast_to(-n_t if n_t[2] > 0 else n_t, X.shape)
    normals, offsets = sensor.laser_planes(cmds)
    frames = render_frames(
        sensor, flat_idx, X, np.ascontiguousarray(N), normals, offsets, light, noise, rng
    )
    stripes = [
        _plane_line(sensor, T_camera_target, n, d) for n, d in zip(normals, offsets, strict=True)
    ]
    truth = SweepTruth(
        commands_v=cmds,
        plane_normals=normals,
        plane_offsets_mm=offsets,
        stripe_uv=stripes,
        target_normal=n_t,
        target_offset_mm=float(n_t @ T_camera_target[:3, 3]),
    )
    return frames, cmds, truth


def _plane_line(sensor: TrueSensor, T_camera_target: F64, n: F64, d: float) -> F64:
    """True stripe on the target: the line of the two planes, projected, clipped to the frame."""
    n_t, d_t = T_camera_target[:3, 2], float(T_camera_target[:3, 2] @ T_camera_target[:3, 3])
    direction = np.cross(n, n_t)
    direction /= np.linalg.norm(direction)
    A = np.stack([n, n_t, direction])
    p = np.linalg.solve(A, np.array([d, d_t, direction @ T_camera_target[:3, 3]]))
    P = p + np.outer(np.linspace(-40.0, 40.0, 8001), direction)
    uv = sensor.project(P)
    inside = (
        (uv[:, 0] > -1)
        & (uv[:, 0] < sensor.width_px)
        & (uv[:, 1] > -1)
        & (uv[:, 1] < sensor.height_px)
        & (P[:, 2] > 0)
    )
    return np.asarray(uv[inside])


def render_chessboard(
    T_camera_target: F64,
    sensor: TrueSensor,
    rng: np.random.Generator,
    *,
    pattern: tuple[int, int] = (9, 6),
    square_mm: float = 2.5,
    noise: NoiseSettings | None = None,
    white: float = 0.7,
    black: float = 0.06,
) -> tuple[Frames, F64, F64]:
    """Render a chessboard under ambient light (no laser).

    pattern: inner corners (columns, rows); the first inner corner is the target origin, squares
    along the target's +x (columns) and +y (rows). Returns the frame shape=(H, W), the true
    corner pixels shape=(cols*rows, 2) in OpenCV's row-major order and the corners' target
    coordinates shape=(cols*rows, 3) [mm].
    """
    noise = noise or NoiseSettings(speckle_contrast=0.0)
    flat_idx, X, t, cosang = _plane_hits(sensor, T_camera_target)
    R, p0 = T_camera_target[:3, :3], T_camera_target[:3, 3]
    local = (X - p0) @ R  # target coordinates
    cols, rows = pattern
    # the squares from -1 .. n_sq along each axis; the plate is white outside the pattern, so
    # the squares' shading is computed on the pattern's pixels only
    ph_u, ph_v = local[:, 0] / square_mm + 1.0, local[:, 1] / square_mm + 1.0
    on = np.flatnonzero((ph_u > 0) & (ph_u < cols + 1) & (ph_v > 0) & (ph_v < rows + 1))
    half_px_mm = 0.5 * t[on] / sensor.fx_px / np.sqrt(np.maximum(np.abs(cosang[on]), 0.2))

    def ramp(ph: F64) -> F64:
        frac = ph - np.floor(ph)
        edge = np.minimum(frac, 1.0 - frac) * square_mm
        sign = np.where(np.floor(ph) % 2 == 0, 1.0, -1.0)
        return np.asarray(sign * np.clip(edge / half_px_mm, 0.0, 1.0))

    val = 0.5 + 0.5 * ramp(ph_u[on]) * ramp(ph_v[on])
    albedo = np.full(len(flat_idx), white)
    albedo[on] = black + (white - black) * val
    irr = np.zeros(sensor.height_px * sensor.width_px, dtype=np.float32)
    irr[flat_idx] = albedo
    frame = form_image(irr.reshape(sensor.height_px, sensor.width_px), noise, rng)
    gx, gy = np.meshgrid(np.arange(cols) * square_mm, np.arange(rows) * square_mm)
    obj = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    corners = sensor.project(obj @ R.T + p0)
    return frame, corners, obj
