"""The rendered path of a body feature: the galvo sweep the true sensor records over a patch of
sheet metal with a round hole, a slot or nothing (a surface point), its thickness seen at the
view's incidence.

Every pixel's ray of the true camera is cast onto the sheet's top face (the feature's plane,
z = 0 of the feature frame F: x along the slot's axis, z the normal out of the sheet). A ray that
meets the face inside the opening goes on into it: it meets the bore's wall (a cylinder for a
hole, a stadium's for a slot) before the bottom face (z = -thickness) or passes through to
nothing (the cell behind the body is far beyond the depth of field: dark). The wall is lit where
the laser sheet reaches it, so the stripe bends down into the hole on the side facing the laser
and its break is not where the top edge is: what the measurement must handle (the edge is the
top face's, as a CMM probes it). The points are shaded and the images formed as the sphere's and
the flat target's (fakes.render: Lambertian sheet-metal, the laser's Gaussian sheet, speckle,
blur, shot and read noise).

    render_feature_sweep(T_camera_feature, kind, size_mm, thickness_mm, sensor, rng, commands_v)
        -> frames (n, H, W) uint8
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from fakes.render import Frames, Lighting, render_frames
from fakes.render_noise import NoiseSettings
from fakes.render_sensor import TrueSensor

F64 = NDArray[np.float64]
#: samples along a ray's path through the sheet to find where it meets the wall
WALL_STEPS = 24


def _inside(kind: str, size_mm: Sequence[float], xy: F64) -> NDArray[np.bool_]:
    """Whether points (n, 2) of the feature's plane lie in its opening."""
    if kind == "hole":
        out: NDArray[np.bool_] = np.hypot(xy[:, 0], xy[:, 1]) < 0.5 * size_mm[0]
        return out
    if kind == "slot":
        w, length = size_mm
        half = max(0.5 * (length - w), 0.0)
        s = np.clip(xy[:, 0], -half, half)
        out = np.hypot(xy[:, 0] - s, xy[:, 1]) < 0.5 * w
        return out
    return np.zeros(len(xy), dtype=bool)


def _wall_normal(kind: str, size_mm: Sequence[float], xy: F64) -> F64:
    """The wall's normal (n, 3) at points (n, 2) on it, into the opening (towards its axis)."""
    if kind == "slot":
        half = max(0.5 * (size_mm[1] - size_mm[0]), 0.0)
        foot = np.column_stack([np.clip(xy[:, 0], -half, half), np.zeros(len(xy))])
    else:
        foot = np.zeros_like(xy)
    d = foot - xy
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.column_stack([d, np.zeros(len(xy))])


def feature_surface(
    T_camera_feature: F64,
    kind: str,
    size_mm: Sequence[float],
    thickness_mm: float,
    sensor: TrueSensor,
) -> tuple[NDArray[np.intp], F64, F64]:
    """The pixels that see the sheet (flat indices), the points they see (camera frame) and the
    surface normals there (towards the camera): the top face off the opening, and the bore's
    wall through it."""
    R, t = T_camera_feature[:3, :3], T_camera_feature[:3, 3]
    rays = sensor.pixel_rays.reshape(-1, 3)
    # rays in the feature frame: origin o = -R^T t, directions R^T r
    o = -R.T @ t
    dirs = rays @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        s_top = -o[2] / dirs[:, 2]
    hit = np.flatnonzero(np.isfinite(s_top) & (s_top > 0))
    top = o + s_top[hit, None] * dirs[hit]
    into = _inside(kind, size_mm, top[:, :2])
    n_top = np.array([0.0, 0.0, 1.0]) if o[2] > 0 else np.array([0.0, 0.0, -1.0])
    face_idx, face_X = hit[~into], top[~into]
    face_N = np.broadcast_to(n_top, face_X.shape)
    # through the opening: the first sample along the ray inside the sheet that is off the
    # opening, refined by bisection, is on the wall (above the bottom face)
    idx, start = hit[into], top[into]
    s_bottom = (-thickness_mm - o[2]) / dirs[idx, 2]
    span = s_bottom - s_top[idx]
    steps = np.linspace(0.0, 1.0, WALL_STEPS + 1)[1:]
    P = start[:, None, :] + (span[:, None] * steps)[:, :, None] * dirs[idx][:, None, :]
    off = ~_inside(kind, size_mm, P[..., :2].reshape(-1, 2)).reshape(P.shape[:2])
    met = off.any(axis=1)
    k = np.argmax(off, axis=1)
    lo = np.where(k > 0, steps[np.maximum(k - 1, 0)], 0.0)[met]
    hi = steps[k][met]
    base, d, sp = start[met], dirs[idx][met], span[met]
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        Q = base + (sp * mid)[:, None] * d
        out = ~_inside(kind, size_mm, Q[:, :2])
        hi, lo = np.where(out, mid, hi), np.where(out, lo, mid)
    wall_X = base + (sp * hi)[:, None] * d
    wall_N = _wall_normal(kind, size_mm, wall_X[:, :2])
    flat = np.concatenate([face_idx, idx[met]])
    X_f = np.concatenate([face_X, wall_X])
    N_f = np.concatenate([face_N, wall_N])
    order = np.argsort(flat, kind="stable")
    X_c = X_f[order] @ R.T + t
    N_c = N_f[order] @ R.T
    return flat[order], X_c, np.ascontiguousarray(N_c)


def render_feature_sweep(
    T_camera_feature: F64,
    kind: str,
    size_mm: Sequence[float],
    thickness_mm: float,
    sensor: TrueSensor,
    rng: np.random.Generator,
    commands_v: F64,
    *,
    noise: NoiseSettings | None = None,
    light: Lighting | None = None,
) -> Frames:
    """Frames (n, H, W) of the sweep at commands_v [V] over the feature posed at
    T_camera_feature (module docstring); sheet metal: albedo 0.6, a faint glint."""
    noise = noise or NoiseSettings()
    light = light or Lighting(albedo=0.6, glint_gain=0.05)
    flat, X, N = feature_surface(T_camera_feature, kind, size_mm, thickness_mm, sensor)
    normals, offsets = sensor.laser_planes(np.asarray(commands_v, dtype=float))
    return render_frames(sensor, flat, X, N, normals, offsets, light, noise, rng)


def bench_pose(tilt_deg: float, roll_deg: float = 0.0) -> F64:
    """T_camera_feature of a feature on a bench: 120 mm in front of the camera, its normal
    towards it, rolled about its normal, tilted about its y axis (towards the laser's side)
    and slightly off-centre (the render tests', bench/edge.py's certified bores)."""
    a, r = np.radians(tilt_deg), np.radians(roll_deg)
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ Ry @ Rz
    T[:3, 3] = [0.4, -0.3, 120.0]
    return T


def bench_commands(true: TrueSensor, half_mm: float, n: int) -> F64:
    """n mirror commands whose laser planes cross 120 mm deep evenly over 0.4 +- half_mm (the
    sweep across a `bench_pose` feature)."""
    grid = np.linspace(-6.0, 6.0, 1201)
    normals, offsets = true.laser_planes(grid)
    x_at = (offsets - normals[:, 2] * 120.0) / normals[:, 0]
    order = np.argsort(x_at)
    out: F64 = np.interp(np.linspace(0.4 - half_mm, 0.4 + half_mm, n), x_at[order], grid[order])
    return out
