"""Triangulation: stripe pixels of a whole sweep -> 3D points in the sensor frame.

Each pixel is undistorted with cv2.undistortPoints (normalised camera coordinates), its ray
through the camera centre is intersected with the laser plane of its frame's mirror command, and
the point is mapped from the camera frame C to the sensor frame S with T_sensor_camera.
`triangulate_profiles` gives a body feature's sweep as its profiles, each point with what the
edge's location needs of its image row (vision.sheet).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from vision.sensor_model import CameraModel, SensorModel
from vision.stripe import StripePoints

F64 = NDArray[np.float64]


def pixel_rays(camera: CameraModel, uv_px: F64) -> F64:
    """Undistorted rays (x, y, 1) shape=(n, 3) of distorted pixels uv_px shape=(n, 2)."""
    if len(uv_px) == 0:
        return np.zeros((0, 3))
    pts = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = np.asarray(
        cv2.undistortPointsIter(
            pts,
            camera.K,
            camera.dist,
            None,
            None,  # type: ignore[call-overload]
            crit,
        )
    ).reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def intersect_planes(rays: F64, normals: F64, offsets: F64) -> F64:
    """Points t * ray on planes n . X = d; rays, normals shape=(n, 3), offsets shape=(n,)."""
    denom = np.einsum("ij,ij->i", rays, normals)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = offsets / denom
    return np.asarray(rays * t[:, None])


def _frames_of(stripes: list[StripePoints]) -> NDArray[np.intp]:
    if not stripes:
        return np.zeros(0, dtype=np.intp)
    return np.concatenate([np.full(len(s), i, dtype=np.intp) for i, s in enumerate(stripes)])


def _to_sensor(
    uv_px: F64, frame_of: NDArray[np.intp], normals: F64, offsets: F64, model: SensorModel
) -> F64:
    """Pixels uv_px (n, 2) on the laser planes of their frames, in S (n, 3); NaN for a point
    behind the camera or on a ray (nearly) parallel to its plane."""
    X_cam = intersect_planes(pixel_rays(model.camera, uv_px), normals[frame_of], offsets[frame_of])
    X_cam[~(np.isfinite(X_cam).all(axis=1) & (X_cam[:, 2] > 0))] = np.nan
    T = model.T_sensor_camera
    out: F64 = X_cam @ T[:3, :3].T + T[:3, 3]
    return out


def triangulate_sweep(
    stripes: list[StripePoints], commands_v: F64, model: SensorModel
) -> tuple[F64, NDArray[np.intp]]:
    """All stripe points of a sweep as 3D points in S.

    stripes: one StripePoints per frame; commands_v: shape=(n_frames,) [V].
    Returns points shape=(n, 3) [mm] in the sensor frame and the frame index of each point.
    Points behind the camera or on rays (nearly) parallel to the plane are dropped.
    """
    if len(stripes) != len(commands_v):
        raise ValueError(f"{len(stripes)} frames but {len(commands_v)} commands")
    frame_of = _frames_of(stripes)
    if frame_of.size == 0:
        return np.zeros((0, 3)), frame_of
    uv = np.column_stack(
        [np.concatenate([s.u_px for s in stripes]), np.concatenate([s.v_px for s in stripes])]
    )
    normals, offsets = model.laser.planes(np.asarray(commands_v, dtype=np.float64))
    X = _to_sensor(uv, frame_of, normals, offsets, model)
    ok = np.isfinite(X).all(axis=1)
    return X[ok], frame_of[ok]


#: the columns of a profile with its light (`triangulate_profiles`)
PROFILE_COLUMNS = 7


def triangulate_profiles(
    stripes: list[StripePoints], commands_v: F64, model: SensorModel
) -> list[F64]:
    """A sweep's profiles with their light: one per frame, its points in the camera's row order,
    in S; each point a row (PROFILE_COLUMNS) of its position [mm] (as `triangulate_sweep`'s),
    the stripe's width along its image row as a vector [mm] (where the point moves when the
    stripe's centre in that row moves by its RMS width: `vision.sheet` puts a row whose light
    an edge has cut back on the face) and its row's flux [DN] (StripePoints.flux_dn). Without
    the flux (stripe points that do not carry it) the profiles are the points alone (n_i, 3)."""
    if len(stripes) != len(commands_v):
        raise ValueError(f"{len(stripes)} frames but {len(commands_v)} commands")
    if any(s.flux_dn is None for s in stripes):
        points, frame_of = triangulate_sweep(stripes, commands_v, model)
        return [points[frame_of == k] for k in range(len(stripes))]
    frame_of = _frames_of(stripes)
    if frame_of.size == 0:
        return [np.zeros((0, PROFILE_COLUMNS)) for _ in stripes]
    u = np.concatenate([s.u_px for s in stripes])
    v = np.concatenate([s.v_px for s in stripes])
    # half the RMS width each side (at least a quarter pixel, so that the row's direction stays)
    half_px = np.maximum(0.5 * np.concatenate([s.width_px for s in stripes]), 0.25)
    flux = np.concatenate([s.flux_dn for s in stripes if s.flux_dn is not None])
    normals, offsets = model.laser.planes(np.asarray(commands_v, dtype=np.float64))
    X = _to_sensor(np.column_stack([u, v]), frame_of, normals, offsets, model)
    ahead = _to_sensor(np.column_stack([u + half_px, v]), frame_of, normals, offsets, model)
    behind = _to_sensor(np.column_stack([u - half_px, v]), frame_of, normals, offsets, model)
    rows = np.column_stack([X, ahead - behind, flux])
    ok = np.isfinite(rows).all(axis=1)
    rows, frame_of = rows[ok], frame_of[ok]
    return [rows[frame_of == k] for k in range(len(stripes))]
