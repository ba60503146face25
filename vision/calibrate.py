"""Sensor calibration: camera intrinsics from chessboards, then the galvo laser model from sweeps
over a flat target seen at several poses.

1. `calibrate_camera`: OpenCV chessboard corners (sub-pixel) and cv2.calibrateCamera (k1, k2,
   p1, p2, k3).
2. `target_plane`: the flat target's plane in the camera frame from its chessboard (solvePnP).
3. `calibrate_laser`: every stripe pixel of a sweep is back-projected onto that pose's target
   plane. A closed-form start: the points of one mirror command from all poses give that
   command's laser plane (SVD); the mirror axis is the line all planes share (the null direction
   of the stacked normals, and the least-squares point); the plane angles about the axis give
   2*theta(command), fitted by a cubic polynomial. Then the whole model (axis, reference normal,
   angle polynomial) is fitted to every point at once: robust least squares of each point's
   distance to the model plane of its command.

The second step is what makes the model hold across the measuring volume. The closed form takes
each command's angle from its plane's normal alone (the direction of points spanning ~20 mm of
depth), not from where the plane lies; a normal error of 0.1 mrad moves the model's plane by
~10 um at the spheres, ~100 mm from the mirror axis. Near the ends of the sweep a command is seen on
one or two target poses only (the stripe leaves the image on the others), so its normal is
poor or its plane is skipped, and the cubic is extrapolated: on the simulated cell (seeds 0-4)
the start's planes missed the calibration points by 16-37 um RMS at the end command (10 um, the
noise, elsewhere), and the spheres at the edges of the field of view, lit by those commands,
failed the free-radius check (bench/sensor_volume.py). The joint fit uses the points' positions
and every command with any points (a single line fixes a plane that must contain the common
axis): 10 um at every command.

At least two target poses that are not parallel are needed (one pose gives one line per command).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vision.errors import CalibrationFailed
from vision.sensor_model import CameraModel, LaserModel, rotate_about_axis
from vision.stripe import StripeSettings, extract_stripe
from vision.triangulate import intersect_planes, pixel_rays

F64 = NDArray[np.float64]
Image = NDArray[np.generic]
_SUBPIX = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)


@dataclass(frozen=True)
class Chessboard:
    """Inner corners (columns, rows) and square size [mm] of the calibration chessboard."""

    pattern: tuple[int, int] = (9, 6)
    square_mm: float = 2.5

    def object_points(self) -> NDArray[np.float32]:
        """Corner coordinates on the board shape=(cols*rows, 3) [mm], OpenCV order."""
        cols, rows = self.pattern
        gx, gy = np.meshgrid(np.arange(cols), np.arange(rows))
        pts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]) * self.square_mm
        return pts.astype(np.float32)


def find_corners(image: Image, board: Chessboard) -> NDArray[np.float32] | None:
    """Sub-pixel chessboard corners shape=(n, 1, 2), or None when the board is not found."""
    raw = np.asarray(image, dtype=np.float64)
    img8 = (
        np.asarray(image, dtype=np.uint8)
        if image.dtype == np.uint8
        else np.asarray(np.clip(raw * (255.0 / max(float(raw.max()), 1.0)), 0, 255), dtype=np.uint8)
    )
    found, corners = cv2.findChessboardCorners(
        img8, board.pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    )
    if not found:
        return None
    return np.asarray(cv2.cornerSubPix(img8, corners, (5, 5), (-1, -1), _SUBPIX))


def calibrate_camera(
    images: Sequence[Image], board: Chessboard | None = None, fix_k3: bool = True
) -> tuple[CameraModel, list[int]]:
    """Intrinsics from chessboard images (all the same size).

    fix_k3: keep k3 = 0; with a 16 mm lens (+-8.7 deg field) k3 is not observable and trades
    off against k2 and the principal point.

    Returns the camera (with its RMS reprojection error) and the indices of the images used.
    Raises CalibrationFailed with fewer than 5 usable views.
    """
    board = board or Chessboard()
    if not images:
        raise CalibrationFailed("no chessboard images")
    h, w = images[0].shape[:2]
    obj, img, used = [], [], []
    for i, image in enumerate(images):
        corners = find_corners(image, board)
        if corners is not None:
            obj.append(board.object_points())
            img.append(corners)
            used.append(i)
    if len(used) < 5:
        raise CalibrationFailed(
            f"chessboard {board.pattern} found in {len(used)} of "
            f"{len(images)} images, at least 5 needed"
        )
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (w, h), None, None, flags=flags)
    camera = CameraModel(
        K=np.asarray(K, np.float64),
        dist=np.asarray(dist, np.float64).ravel()[:5],
        width_px=w,
        height_px=h,
        rms_reprojection_px=float(rms),
    )
    return camera, used


def target_plane(
    image: Image, camera: CameraModel, board: Chessboard | None = None
) -> tuple[F64, float]:
    """The target's plane n . X = d in the camera frame (n toward the camera's +z side)."""
    board = board or Chessboard()
    corners = find_corners(image, board)
    if corners is None:
        raise CalibrationFailed("chessboard not found in the target image")
    ok, rvec, tvec = cv2.solvePnP(board.object_points(), corners, camera.K, camera.dist)
    if not ok:
        raise CalibrationFailed("solvePnP failed on the target image")
    R, _ = cv2.Rodrigues(rvec)
    n = np.asarray(R[:, 2], dtype=np.float64)
    n = n if n[2] > 0 else -n
    return n, float(n @ np.asarray(tvec, np.float64).ravel())


def _fit_plane(X: F64) -> tuple[F64, float, float]:
    """Least-squares plane of points shape=(n, 3): normal (n_x >= 0), offset, RMS distance."""
    m = X.mean(axis=0)
    _, s, vt = np.linalg.svd(X - m, full_matrices=False)
    n = vt[2] if vt[2][0] >= 0 else -vt[2]
    return n, float(n @ m), float(s[2] / np.sqrt(len(X)))


def laser_points(
    frames: Iterable[Image],
    plane: tuple[F64, float],
    camera: CameraModel,
    mode: str = "fast",
    settings: StripeSettings | None = None,
) -> list[F64]:
    """Stripe points of each frame of a target sweep, on the target plane: list of (n_i, 3)."""
    out = []
    for frame in frames:
        pts = extract_stripe(np.asarray(frame), mode, settings)
        rays = pixel_rays(camera, np.column_stack([pts.u_px, pts.v_px]))
        n = np.broadcast_to(plane[0], rays.shape)
        out.append(intersect_planes(rays, n, np.full(len(rays), plane[1])))
    return out


def _spread_mm(X: F64) -> float:
    """RMS extent of points (n, 3) across their main line [mm]: ~0 when they are collinear."""
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return float(s[1] / np.sqrt(len(X)))


def calibrate_laser(
    points_per_pose: Sequence[Sequence[F64]],
    commands_v: F64,
    min_points: int = 200,
    min_spread_mm: float = 0.5,
) -> LaserModel:
    """Laser model from target sweeps: points_per_pose[k][i] are the 3D points [mm, camera
    frame] of command commands_v[i] on target pose k (all poses swept with the same commands).
    The closed-form start fits a command's plane only when its points span it (at least
    `min_spread_mm` RMS across their main line: the target poses must not be identical or
    parallel) and needs 5 such commands; the joint fit then uses every point (module docstring).
    rms_plane_mm: RMS distance of all points to their command's model plane.
    """
    start = _laser_closed_form(points_per_pose, commands_v, min_points, min_spread_mm)
    return _refine_laser(start, points_per_pose, np.asarray(commands_v, dtype=np.float64))


def _laser_closed_form(
    points_per_pose: Sequence[Sequence[F64]],
    commands_v: F64,
    min_points: int,
    min_spread_mm: float,
) -> LaserModel:
    """The start of `calibrate_laser`: one plane per command, the axis and angles from them."""
    cmds = np.asarray(commands_v, dtype=np.float64)
    normals, offsets, used = [], [], []
    for i in range(len(cmds)):
        X = np.concatenate(
            [pose[i] for pose in points_per_pose if len(pose[i])] or [np.zeros((0, 3))]
        )
        lines = sum(1 for pose in points_per_pose if len(pose[i]) >= 20)
        if len(X) < min_points or lines < 2 or _spread_mm(X) < min_spread_mm:
            continue  # identical or parallel target poses put every point on one line
        n, d, _ = _fit_plane(X)
        normals.append(n)
        offsets.append(d)
        used.append(cmds[i])
    if len(used) < 5:
        raise CalibrationFailed(
            f"laser planes determined for {len(used)} commands, "
            "at least 5 needed (two non-parallel target poses per command)"
        )
    N, D, C = np.array(normals), np.array(offsets), np.array(used)
    _, _, vt = np.linalg.svd(N)
    u = vt[2] if vt[2][1] >= 0 else -vt[2]
    p = np.linalg.lstsq(N, D, rcond=1e-6)[0]
    base = N[int(np.argmin(np.abs(C)))]
    beta = np.arctan2(np.cross(base, N) @ u, N @ base)
    coef = np.polynomial.polynomial.polyfit(C, beta, 3)
    n0 = rotate_about_axis(base, u, float(coef[0]))
    poly = np.concatenate([[0.0], coef[1:] / 2.0])
    n0 = n0 - u * (u @ n0)
    return LaserModel(
        axis_point_mm=p - u * (u @ p),
        axis_dir=u,
        ref_normal=n0 / np.linalg.norm(n0),
        angle_poly_rad=poly,
    )


def _rotation(w: F64) -> F64:
    """Rotation matrix of the rotation vector w shape=(3,) [rad]."""
    R, _ = cv2.Rodrigues(np.asarray(w, dtype=np.float64).reshape(3, 1))
    return np.asarray(R, dtype=np.float64)


def _refine_laser(
    start: LaserModel, points_per_pose: Sequence[Sequence[F64]], cmds: F64
) -> LaserModel:
    """The laser model fitted to all points: minimise the robust sum over points of their
    distance to the model plane of their command. Unknowns (8): a small rotation of the axis
    and reference normal together (3; the turn about the axis is the angle polynomial's
    constant, kept 0), the axis point's shift across the axis (2), the polynomial's linear,
    quadratic and cubic coefficients (3)."""
    chunks = [(P, cmds[i]) for pose in points_per_pose for i, P in enumerate(pose) if len(P)]
    X = np.concatenate([P for P, _ in chunks])
    V = np.vander(np.concatenate([np.full(len(P), c) for P, c in chunks]), 4, increasing=True)
    u0, n00 = start.axis_dir, start.ref_normal
    p0, e2 = start.axis_point_mm, np.cross(u0, n00)

    def model(x: F64) -> tuple[F64, F64, F64, F64]:
        R = _rotation(x[:3])
        return R @ u0, R @ n00, p0 + x[3] * n00 + x[4] * e2, np.concatenate([[0.0], x[5:]])

    def residuals(x: F64) -> F64:
        u, n0, p, poly = model(x)
        n = rotate_about_axis(n0, u, 2.0 * (V @ poly))
        return np.asarray(np.einsum("ij,ij->i", n, X - p))

    x0 = np.concatenate([np.zeros(5), start.angle_poly_rad[1:4]])
    r0 = residuals(x0)
    scale = max(1.4826 * float(np.median(np.abs(r0 - np.median(r0)))), 1e-4)
    from scipy.optimize import least_squares  # here: about half a second to import

    fit = least_squares(residuals, x0, loss="soft_l1", f_scale=2.0 * scale, x_scale="jac")
    u, n0, p, poly = model(fit.x)
    n0 = n0 - u * (u @ n0)
    r = residuals(fit.x)
    return LaserModel(
        axis_point_mm=p - u * (u @ p),
        axis_dir=u / np.linalg.norm(u),
        ref_normal=n0 / np.linalg.norm(n0),
        angle_poly_rad=poly,
        rms_plane_mm=float(np.sqrt(np.mean(np.square(r)))),
    )
