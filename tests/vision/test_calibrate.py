"""Sensor calibration from rendered chessboards and flat-target sweeps, checked against truth."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.render import default_sweep_commands, render_sphere_sweep
from fakes.render_sensor import TrueSensor
from fakes.render_targets import CalibrationSet, render_calibration_set
from vision.calibrate import calibrate_camera, calibrate_laser, laser_points, target_plane
from vision.calibrate_sensor import calibrate_sensor
from vision.errors import CalibrationFailed
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import LaserModel, SensorModel


@pytest.fixture(scope="module")
def calib_set(true_sensor: TrueSensor) -> CalibrationSet:
    return render_calibration_set(
        true_sensor, np.random.default_rng(11), n_chessboards=12, n_targets=4, n_commands=9
    )


@pytest.fixture(scope="module")
def calibrated(calib_set: CalibrationSet) -> SensorModel:
    return calibrate_sensor(calib_set.chessboards, calib_set.targets, calib_set.commands_v)


def test_intrinsics(calibrated: SensorModel, true_sensor: TrueSensor) -> None:
    K = calibrated.camera.K
    assert abs(K[0, 0] / true_sensor.fx_px - 1) < 2e-3
    assert abs(K[0, 2] - true_sensor.cx_px) < 5 and abs(K[1, 2] - true_sensor.cy_px) < 5
    assert calibrated.camera.rms_reprojection_px is not None
    assert calibrated.camera.rms_reprojection_px < 0.1


def test_target_plane_from_the_chessboard(
    calib_set: CalibrationSet, calibrated: SensorModel
) -> None:
    T = calib_set.target_poses[0]
    n, d = target_plane(calib_set.targets[0][0], calibrated.camera)
    n_true = T[:3, 2] * np.sign(T[2, 2])
    assert np.degrees(np.arccos(min(1.0, float(n @ n_true)))) < 0.1
    assert abs(d - float(n_true @ T[:3, 3])) < 0.05


def test_laser_planes_match_the_truth(calibrated: SensorModel, true_sensor: TrueSensor) -> None:
    cmds = np.linspace(-3.0, 3.0, 7)
    n_cal, d_cal = calibrated.laser.planes(cmds)
    n_true, d_true = true_sensor.laser_planes(cmds)
    sign = np.sign(np.einsum("ij,ij->i", n_cal, n_true))
    # distance between the planes at points of the measuring volume
    grid = np.array([[x, y, z] for x in (-15, 15) for y in (-12, 12) for z in (118, 140)], float)
    gap = np.abs(grid @ n_cal.T - d_cal - sign * (grid @ n_true.T - d_true))
    # dominated by the principal point of this 12-view calibration (a few px): over 26 render
    # seeds the largest gap at these corners of the volume was 0.03-0.21 mm (median 0.08)
    assert gap.max() < 0.25


def test_calibrated_sensor_measures_spheres(
    calibrated: SensorModel, true_sensor: TrueSensor
) -> None:
    rng = np.random.default_rng(3)
    c = np.array([1.0, -1.0, 129.0])
    frames, cmds, _ = render_sphere_sweep(
        c, 15.0, true_sensor, rng, commands_v=default_sweep_commands(20, 3.2)
    )
    m = measure_sphere_from_sweep(frames, cmds, calibrated)
    # absolute error: dominated by the intrinsics (focal length, principal point); see the bench
    assert np.linalg.norm(m.c_sensor_mm - c) < 0.15


def _plane_gap_um(laser: LaserModel, sensor: TrueSensor, command_v: float) -> float:
    """Largest distance [um] of the model's plane from the true plane of a command, over the
    part of the true plane in view at the depths where the measuring volume's spheres are lit
    (108-137 mm: the near caps of spheres centred 125-135 mm away, radius 15 mm)."""
    nt, dt = sensor.laser_planes(np.array([command_v]))
    ys, zs = np.meshgrid(np.linspace(-15.0, 15.0, 13), np.linspace(108.0, 137.0, 15))
    xs = (dt[0] - nt[0, 1] * ys - nt[0, 2] * zs) / nt[0, 0]
    P = np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1)
    uv = sensor.project(P)
    P = P[(uv[:, 0] >= 0) & (uv[:, 0] < sensor.width_px)]
    P = P[(sensor.project(P)[:, 1] >= 0) & (sensor.project(P)[:, 1] < sensor.height_px)]
    n, d = laser.planes(np.array([command_v]))
    return 1000.0 * float(np.abs(P @ n[0] - d[0]).max())


def test_laser_model_holds_at_the_ends_of_the_sweep(
    calib_set: CalibrationSet, true_sensor: TrueSensor, perfect_model: SensorModel
) -> None:
    """Issue 27: with the true intrinsics, the laser model is right wherever the spheres are
    lit, the ends of the sweep included (the commands seen on one or two target poses only).
    The closed-form model (each command's angle from its plane's normal alone, a cubic through
    them) was 19 um off at -3.2 V on this set and 13-30 um on seeds 0-4 of the cell, enough to
    fail the free-radius check at the edges of the field of view; the joint fit is 3-7 um."""
    camera = perfect_model.camera
    points = [
        laser_points(frames, target_plane(board, camera), camera)
        for board, frames in calib_set.targets
    ]
    laser = calibrate_laser(points, calib_set.commands_v)
    gaps = [_plane_gap_um(laser, true_sensor, v) for v in np.linspace(-3.2, 3.2, 9)]
    assert max(gaps) < 10.0, np.round(gaps, 1)
    assert laser.rms_plane_mm is not None and laser.rms_plane_mm < 0.015  # the noise: ~10 um


def test_calibrated_sensor_measures_the_corners_of_the_volume(
    calibrated: SensorModel, true_sensor: TrueSensor
) -> None:
    """Issue 27: spheres near the 8 corners of the measuring volume (field of view 37 x 27 mm,
    depth 125-135 mm) measured with the calibrated sensor pass the quality checks, their free
    radius within 30 um of the certified one, and the centre error is uniform: within 40 um of
    its mean (what the intrinsics leave: a common offset of ~0.15 mm on this set, which the
    hand-eye absorbs). Before the joint laser fit the free radius was 49 um off at
    (17, 12, 135) (rejected) and 33 um at (17, -12, 135)."""
    rng = np.random.default_rng(5)
    commands = default_sweep_commands(24, 3.2)
    errors, devs = [], []
    for c in [
        np.array([x, y, z]) for z in (125.0, 135.0) for y in (-12.0, 12.0) for x in (-17, 17)
    ]:
        frames, cmds, _ = render_sphere_sweep(
            c, 15.0, true_sensor, rng, commands_v=commands, stripe_truth=False
        )
        m = measure_sphere_from_sweep(frames, cmds, calibrated)  # raises when rejected
        errors.append(m.c_sensor_mm - c)
        devs.append(m.quality.radius_dev_mm)
    e = np.array(errors)
    assert np.abs(devs).max() < 0.03, np.round(devs, 4)
    assert np.linalg.norm(e, axis=1).max() < 0.2
    assert np.linalg.norm(e - e.mean(axis=0), axis=1).max() < 0.04, np.round(1000 * e)


def test_insufficient_data_is_a_typed_error(
    calib_set: CalibrationSet, calibrated: SensorModel
) -> None:
    with pytest.raises(CalibrationFailed, match="at least 5"):
        calibrate_camera(calib_set.chessboards[:3])
    blank = np.zeros_like(calib_set.chessboards[0])
    with pytest.raises(CalibrationFailed, match="not found"):
        target_plane(blank, calibrated.camera)
    image, frames = calib_set.targets[0]
    one_pose = [laser_points(frames, target_plane(image, calibrated.camera), calibrated.camera)]
    with pytest.raises(CalibrationFailed, match="non-parallel"):
        calibrate_laser(one_pose, calib_set.commands_v)


def test_identical_target_poses_do_not_determine_the_laser(
    calib_set: CalibrationSet, calibrated: SensorModel
) -> None:
    """The same target pose recorded twice puts every command's points on one line: no plane,
    so the calibration fails instead of writing a degenerate laser model."""
    image, frames = calib_set.targets[0]
    pose = laser_points(frames, target_plane(image, calibrated.camera), calibrated.camera)
    with pytest.raises(CalibrationFailed, match="non-parallel"):
        calibrate_laser([pose, [p.copy() for p in pose]], calib_set.commands_v)
