"""The laser-line sensor's geometric model and its calibration file (TOML).

Frames: S (sensor) is the frame sphere centres are reported in; C (camera) is OpenCV's camera frame
(origin at the projection centre, z along the optical axis toward the scene, x along image
columns, y along image rows). By default S = C (`T_sensor_camera` = identity).

Camera: pinhole with OpenCV distortion (k1, k2, p1, p2, k3).
Laser: a one-mirror galvanometer. The laser plane always contains the mirror axis (the axis lies
in the mirror surface and the incoming fan hits the mirror along it). At mechanical mirror angle
theta the plane normal is the reference normal rotated by 2*theta about the axis. The mirror
angle follows the command (DAC volts) through a polynomial: theta = sum_k a_k * command**k.

File format (`rvis-sensor/1`, all lengths in mm, angles in degrees at this boundary)::

    format = "rvis-sensor/1"
    name = "simulated default"
    [camera]
    width_px = 1296
    height_px = 966
    fx_px = 4266.667          # focal length in pixels (16 mm / 3.75 um)
    fy_px = 4266.667
    cx_px = 647.5             # principal point, pixel centres at integers
    cy_px = 482.5
    dist = [-0.08, 0.15, 0.0001, -0.0001, 0.0]   # OpenCV order k1, k2, p1, p2, k3
    [laser]
    axis_point_mm = [70.0, 0.0, 0.0]      # a point on the mirror axis, camera frame
    axis_dir = [0.0, 1.0, 0.0]            # unit direction of the mirror axis, camera frame
    ref_normal = [0.866, 0.0, 0.5]        # plane normal at theta = 0 (unit, normal to the axis)
    angle_poly_deg = [0.0, 1.0, 0.0, 0.0] # theta_deg = sum a_k * command_V**k
    [sensor]
    T_sensor_camera = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]

Optional keys written by `rvis sensor calibrate`: `camera.rms_reprojection_px`,
`laser.rms_plane_mm`.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vision.errors import SensorFileError

FORMAT = "rvis-sensor/1"
F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole camera with OpenCV distortion.

    K: shape=(3, 3) [px]; dist: shape=(5,) OpenCV (k1, k2, p1, p2, k3); size in pixels.
    """

    K: F64
    dist: F64
    width_px: int
    height_px: int
    rms_reprojection_px: float | None = None


@dataclass(frozen=True, eq=False)
class LaserModel:
    """Galvo laser plane family: planes through the mirror axis, normal rotated by 2*theta.

    axis_point_mm: shape=(3,) [mm] camera frame; axis_dir, ref_normal: shape=(3,) unit;
    angle_poly_rad: ascending polynomial coefficients, theta [rad] of command [V].
    """

    axis_point_mm: F64
    axis_dir: F64
    ref_normal: F64
    angle_poly_rad: F64
    rms_plane_mm: float | None = None

    def mirror_angle_rad(self, command: F64 | float) -> F64:
        """Mechanical mirror angle [rad] for command(s) [V], same shape as `command`."""
        return np.asarray(np.polynomial.polynomial.polyval(command, self.angle_poly_rad))

    def planes(self, command: F64 | float) -> tuple[F64, F64]:
        """Laser planes for command(s): normals shape=(..., 3) and offsets shape=(...) [mm].

        A point X [mm, camera frame] lies on the plane when n . X = d.
        """
        theta = self.mirror_angle_rad(np.asarray(command, dtype=np.float64))
        n = rotate_about_axis(self.ref_normal, self.axis_dir, 2.0 * theta)
        return n, n @ self.axis_point_mm


@dataclass(frozen=True, eq=False)
class SensorModel:
    """Camera + laser + the pose of the camera in the sensor frame (T_sensor_camera, 4x4)."""

    camera: CameraModel
    laser: LaserModel
    T_sensor_camera: F64 = field(default_factory=lambda: np.eye(4))
    name: str = "unnamed"


def rotate_about_axis(v: F64, axis: F64, angle_rad: F64 | float) -> F64:
    """Rodrigues: rotate vector v shape=(3,) about unit `axis` by angle(s); shape=(..., 3)."""
    a = np.asarray(angle_rad, dtype=np.float64)[..., None]
    k = axis / np.linalg.norm(axis)
    return np.asarray(v * np.cos(a) + np.cross(k, v) * np.sin(a) + k * (k @ v) * (1.0 - np.cos(a)))


def default_sensor_model() -> SensorModel:
    """The nominal design of the simulated sensor (the renderer's default truth matches it).

    16 mm lens on 3.75 um pixels: fx = 4266.7 px; field of view 37 x 27 mm at 120 mm.
    Mirror axis 70 mm from the camera along +x, roughly parallel to the image rows, so the
    stripe runs along the rows and the sweep moves it across the columns; at theta = 0 the
    plane meets the optical axis at z = 121 mm with a triangulation angle of 30 deg.
    """
    f_px = 16.0 / 0.00375
    K = np.array([[f_px, 0.0, 647.5], [0.0, f_px, 482.5], [0.0, 0.0, 1.0]])
    dist = np.array([-0.08, 0.15, 1e-4, -1e-4, 0.0])
    axis_dir = np.array([0.0, 1.0, 0.01])
    axis_dir /= np.linalg.norm(axis_dir)
    beta = math.radians(30.0)  # plane tilt from the optical axis at theta = 0
    n0 = np.cross(axis_dir, [-math.sin(beta), 0.0, math.cos(beta)])  # plane holds the axis
    n0 /= np.linalg.norm(n0)
    laser = LaserModel(
        axis_point_mm=np.array([70.0, 0.0, 0.0]),
        axis_dir=axis_dir,
        ref_normal=n0,
        angle_poly_rad=np.radians([0.0, 1.0, 0.004, 0.0]),
    )
    camera = CameraModel(K=K, dist=dist, width_px=1296, height_px=966)
    return SensorModel(camera=camera, laser=laser, name="simulated default")


def _vec(table: dict[str, Any], key: str, n: int, section: str) -> F64:
    name = f"{section}.{key}"
    if key not in table:
        raise SensorFileError("missing", field=name)
    try:
        arr = np.asarray(table[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SensorFileError("not a list of numbers", field=name) from exc
    if arr.ndim != 1 or (n > 0 and arr.shape[0] != n) or not np.all(np.isfinite(arr)):
        raise SensorFileError(f"expected {n if n > 0 else 'some'} finite numbers", field=name)
    return arr


def _num(table: dict[str, Any], key: str, section: str) -> float:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SensorFileError("missing or not a finite number", field=f"{section}.{key}")
    return float(value)


def _unit(v: F64, name: str) -> F64:
    norm = float(np.linalg.norm(v))
    if norm < 1e-9:
        raise SensorFileError("zero vector", field=name)
    return v / norm


def sensor_model_from_dict(doc: dict[str, Any]) -> SensorModel:
    """Build and validate a SensorModel from a parsed `rvis-sensor/1` document."""
    if doc.get("format") != FORMAT:
        raise SensorFileError(f"expected '{FORMAT}'", field="format")
    cam = doc.get("camera")
    las = doc.get("laser")
    if not isinstance(cam, dict) or not isinstance(las, dict):
        raise SensorFileError("sections [camera] and [laser] are required")
    fx, fy = _num(cam, "fx_px", "camera"), _num(cam, "fy_px", "camera")
    if fx <= 0 or fy <= 0:
        raise SensorFileError("focal lengths must be positive", field="camera.fx_px")
    K = np.array(
        [
            [fx, 0.0, _num(cam, "cx_px", "camera")],
            [0.0, fy, _num(cam, "cy_px", "camera")],
            [0.0, 0.0, 1.0],
        ]
    )
    width, height = _num(cam, "width_px", "camera"), _num(cam, "height_px", "camera")
    rms_px = cam.get("rms_reprojection_px")
    camera = CameraModel(
        K=K,
        dist=_vec(cam, "dist", 5, "camera"),
        width_px=int(width),
        height_px=int(height),
        rms_reprojection_px=None if rms_px is None else float(rms_px),
    )
    axis_dir = _unit(_vec(las, "axis_dir", 3, "laser"), "laser.axis_dir")
    n0 = _unit(_vec(las, "ref_normal", 3, "laser"), "laser.ref_normal")
    if abs(float(n0 @ axis_dir)) > 1e-3:
        raise SensorFileError("must be normal to laser.axis_dir", field="laser.ref_normal")
    n0 = _unit(n0 - axis_dir * (n0 @ axis_dir), "laser.ref_normal")
    poly = _vec(las, "angle_poly_deg", 0, "laser")
    rms_mm = las.get("rms_plane_mm")
    laser = LaserModel(
        axis_point_mm=_vec(las, "axis_point_mm", 3, "laser"),
        axis_dir=axis_dir,
        ref_normal=n0,
        angle_poly_rad=np.radians(poly),
        rms_plane_mm=None if rms_mm is None else float(rms_mm),
    )
    T = np.eye(4)
    sensor = doc.get("sensor", {})
    if isinstance(sensor, dict) and "T_sensor_camera" in sensor:
        T = np.asarray(sensor["T_sensor_camera"], dtype=np.float64)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise SensorFileError(
                "expected a 4x4 homogeneous matrix", field="sensor.T_sensor_camera"
            )
    return SensorModel(
        camera=camera, laser=laser, T_sensor_camera=T, name=str(doc.get("name", "unnamed"))
    )


def load_sensor_model(path: str | Path) -> SensorModel:
    """Read a sensor-calibration TOML file; SensorFileError names the bad field."""
    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise SensorFileError(f"cannot read: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise SensorFileError(f"not UTF-8 text ({exc.reason})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SensorFileError(f"not valid TOML ({exc})") from exc
    return sensor_model_from_dict(doc)


def _fmt(values: F64) -> str:
    return "[" + ", ".join(repr(float(v)) for v in np.ravel(values)) + "]"


def dumps_sensor_model(model: SensorModel) -> str:
    """The model as `rvis-sensor/1` TOML text (floats written with full precision)."""
    K, cam, las = model.camera.K, model.camera, model.laser
    lines = [
        f'format = "{FORMAT}"',
        f"name = {json.dumps(model.name)}",
        "",
        "[camera]",
        f"width_px = {cam.width_px}",
        f"height_px = {cam.height_px}",
        f"fx_px = {float(K[0, 0])!r}",
        f"fy_px = {float(K[1, 1])!r}",
        f"cx_px = {float(K[0, 2])!r}",
        f"cy_px = {float(K[1, 2])!r}",
        f"dist = {_fmt(cam.dist)}",
    ]
    if cam.rms_reprojection_px is not None:
        lines.append(f"rms_reprojection_px = {cam.rms_reprojection_px!r}")
    lines += [
        "",
        "[laser]",
        f"axis_point_mm = {_fmt(las.axis_point_mm)}",
        f"axis_dir = {_fmt(las.axis_dir)}",
        f"ref_normal = {_fmt(las.ref_normal)}",
        f"angle_poly_deg = {_fmt(np.degrees(las.angle_poly_rad))}",
    ]
    if las.rms_plane_mm is not None:
        lines.append(f"rms_plane_mm = {las.rms_plane_mm!r}")
    rows = ", ".join(_fmt(row) for row in model.T_sensor_camera)
    lines += ["", "[sensor]", f"T_sensor_camera = [{rows}]", ""]
    return "\n".join(lines)


def save_sensor_model(model: SensorModel, path: str | Path) -> None:
    """Write the model as a `rvis-sensor/1` TOML file."""
    Path(path).write_text(dumps_sensor_model(model), encoding="utf-8")
