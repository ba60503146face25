"""Sensor model: the laser-plane family, the TOML file format and its validation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fakes.render_sensor import TrueSensor
from vision.errors import SensorFileError
from vision.sensor_model import (
    SensorModel,
    default_sensor_model,
    dumps_sensor_model,
    load_sensor_model,
    save_sensor_model,
)

COMMANDS_V = np.linspace(-3.5, 3.5, 8)


def _same_planes(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> float:
    sign = np.sign(np.einsum("ij,ij->i", a[0], b[0]))[:, None]
    return float(max(np.abs(a[0] - sign * b[0]).max(), np.abs(a[1] - sign[:, 0] * b[1]).max()))


def test_default_model_is_the_renderers_truth(true_sensor: TrueSensor) -> None:
    model = default_sensor_model()
    assert _same_planes(model.laser.planes(COMMANDS_V), true_sensor.laser_planes(COMMANDS_V)) < 1e-9
    # the camera too: the renderer's truth is written independently of the estimators' model
    # (fakes/ does not import vision/), so this is where the two declarations are held equal
    cam, t = model.camera, true_sensor
    assert (cam.width_px, cam.height_px) == (t.width_px, t.height_px)
    k_true = np.array([[t.fx_px, 0.0, t.cx_px], [0.0, t.fy_px, t.cy_px], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(np.asarray(cam.K, dtype=float), k_true)
    np.testing.assert_allclose(np.ravel(cam.dist), t.dist)


def test_planes_contain_the_mirror_axis_and_turn_twice_the_mirror_angle() -> None:
    laser = default_sensor_model().laser
    n, d = laser.planes(np.array([0.0, 1.0]))
    for k in (-50.0, 0.0, 50.0):
        p = laser.axis_point_mm + k * laser.axis_dir
        assert np.allclose(n @ p, d, atol=1e-9)
    theta = laser.mirror_angle_rad(1.0) - laser.mirror_angle_rad(0.0)
    assert math.isclose(math.acos(float(n[0] @ n[1])), 2 * float(theta), rel_tol=1e-9)


def test_default_geometry_matches_the_paper_camera() -> None:
    cam = default_sensor_model().camera
    fov_x = cam.width_px / cam.K[0, 0] * 120.0
    fov_y = cam.height_px / cam.K[1, 1] * 120.0
    assert 36.0 < fov_x < 37.5 and 26.5 < fov_y < 27.5
    # the plane at command 0 meets the optical axis near the working distance, at ~30 deg
    n, d = default_sensor_model().laser.planes(0.0)
    assert 115.0 < d / n[2] < 128.0


def test_toml_round_trip_is_exact(tmp_path: Path) -> None:
    model = default_sensor_model()
    path = tmp_path / "sensor.toml"
    save_sensor_model(model, path)
    back = load_sensor_model(path)
    assert np.array_equal(back.camera.K, model.camera.K)
    assert np.array_equal(back.camera.dist, model.camera.dist)
    assert _same_planes(back.laser.planes(COMMANDS_V), model.laser.planes(COMMANDS_V)) < 1e-12
    assert back.name == model.name and np.array_equal(back.T_sensor_camera, np.eye(4))


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ('format = "rvis-sensor/1"', 'format = "other"', "format"),
        ("fx_px = ", "fx_px = -", "camera.fx_px"),
        ("dist = [", "dist = [1.0, ", "camera.dist"),
        ("axis_dir = [", "axis_dir = [0.0, ", "laser.axis_dir"),
        ("ref_normal = [", "ref_normal = [0.0, 1.0, 0.0] #", "laser.ref_normal"),
    ],
)
def test_bad_files_name_the_field(tmp_path: Path, old: str, new: str, field: str) -> None:
    text = dumps_sensor_model(default_sensor_model())
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(SensorFileError) as info:
        load_sensor_model(path)
    assert info.value.field == field


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(SensorFileError, match="cannot read"):
        load_sensor_model(tmp_path / "missing.toml")
    bad = tmp_path / "x.toml"
    bad.write_text("format = [")
    with pytest.raises(SensorFileError, match="not valid TOML"):
        load_sensor_model(bad)


def test_sensor_frame_offset_is_applied(perfect_model: SensorModel) -> None:
    assert np.array_equal(perfect_model.T_sensor_camera, np.eye(4))
