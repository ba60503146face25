"""Triangulation: stripe pixels of a whole sweep -> 3D points in the sensor frame.

Each pixel is undistorted with cv2.undistortPoints (normalised camera coordinates), its ray
through the camera centre is intersected with the laser plane of its frame's mirror command, and
the point is mapped from the camera frame C to the sensor frame S with T_sensor_camera.
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
    frame_of = (
        np.concatenate([np.full(len(s), i, dtype=np.intp) for i, s in enumerate(stripes)])
        if stripes
        else np.zeros(0, dtype=np.intp)
    )
    if frame_of.size == 0:
        return np.zeros((0, 3)), frame_of
    uv = np.column_stack(
        [np.concatenate([s.u_px for s in stripes]), np.concatenate([s.v_px for s in stripes])]
    )
    normals, offsets = model.laser.planes(np.asarray(commands_v, dtype=np.float64))
    rays = pixel_rays(model.camera, uv)
    X_cam = intersect_planes(rays, normals[frame_of], offsets[frame_of])
    ok = np.isfinite(X_cam).all(axis=1) & (X_cam[:, 2] > 0)
    T = model.T_sensor_camera
    X_sensor = X_cam[ok] @ T[:3, :3].T + T[:3, 3]
    return X_sensor, frame_of[ok]
