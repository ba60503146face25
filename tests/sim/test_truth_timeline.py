"""The cell's truth over sim time: warm-up of the temperature, the knock on the sensor mount,
and the fixed validation positions the app measures the true error at."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from app.sim.cell import collect, make_cell
from calib.identify import identify
from fakes.cell import SimulatedCell
from fakes.clock import ScaledClock
from fakes.line_truth import LineTruth, validation_positions
from fakes.truth import Knock, Warmup

HOUR_S = 3600.0


def rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def timed_cell(cfg: CellConfig, seed: int, **kw: object) -> SimulatedCell:
    cell = make_cell(cfg, seed=seed)
    cell.set_timeline(ScaledClock(1.0, started=False), **kw)  # type: ignore[arg-type]
    return cell


def test_warm_up_is_first_order_about_8_k_over_3_h(cfg: CellConfig) -> None:
    cell = timed_cell(cfg, 0, warmup=Warmup(rise_k=8.0, tau_s=HOUR_S))
    ambient = cfg.simulation["temp_c"]
    assert cell.temp_at(0.0) == ambient
    assert cell.temp_c == ambient  # the clock stands at 0
    assert cell.temp_at(HOUR_S) - ambient == pytest.approx(8.0 * (1 - np.exp(-1)), abs=1e-9)
    assert cell.temp_at(3 * HOUR_S) - ambient == pytest.approx(7.60, abs=0.01)
    temps = [cell.temp_at(t) for t in np.linspace(0, 8 * HOUR_S, 50)]
    assert np.all(np.diff(temps) > 0) and temps[-1] - ambient < 8.0


def test_the_warm_up_moves_the_true_pose_as_the_temperature_does(cfg: CellConfig) -> None:
    q = np.array([[20.0, 10.0, -5.0, 30.0, -60.0, 10.0], [-70.0, 30.0, 10.0, 0.0, -90.0, 0.0]])
    cell = timed_cell(cfg, 1, warmup=Warmup())
    at_3h = cell.T_part_sensor(q, 3 * HOUR_S)
    fixed = make_cell(cfg, seed=1)
    fixed.temp_c = cell.temp_at(3 * HOUR_S)
    np.testing.assert_allclose(at_3h, fixed.T_part_sensor(q), atol=1e-12)
    moved_mm = np.linalg.norm(at_3h[:, :3, 3] - cell.T_part_sensor(q, 0.0)[:, :3, 3], axis=1)
    assert np.all((moved_mm > 0.03) & (moved_mm < 0.5))  # 11.5 um/m/K, ~2 m, 7.6 K


def test_the_knock_moves_the_sensor_mount_by_the_configured_amount(cfg: CellConfig) -> None:
    knock = Knock(at_s=2 * HOUR_S, shift_mm=0.3, tilt_deg=0.05)
    cell = timed_cell(cfg, 2, knock=knock)
    before, after = cell.mount_at(knock.at_s - 1.0), cell.mount_at(knock.at_s)
    np.testing.assert_array_equal(before, cell.mount_at(0.0))
    delta = np.linalg.inv(before) @ after  # the knock in the sensor frame
    assert np.linalg.norm(delta[:3, 3]) == pytest.approx(0.3, abs=1e-9)
    assert rotation_deg(delta[:3, :3]) == pytest.approx(0.05, abs=1e-6)
    q = np.array([[10.0, 20.0, 0.0, 0.0, -70.0, 0.0]])
    shift = cell.T_part_sensor(q, knock.at_s)[0, :3, 3] - cell.T_part_sensor(q, 0.0)[0, :3, 3]
    assert np.linalg.norm(shift) == pytest.approx(0.3, abs=1e-6)  # no warm-up: only the knock


def test_the_knock_direction_comes_from_the_seed(cfg: CellConfig) -> None:
    knock = Knock(at_s=0.0)

    def shift(seed: int) -> np.ndarray:
        cell = timed_cell(cfg, seed, knock=knock)
        return np.linalg.inv(cell.mount_at(-1.0)) @ cell.mount_at(0.0)

    np.testing.assert_array_equal(shift(3), shift(3))
    assert not np.allclose(shift(3), shift(4))


def test_validation_positions_are_seen_and_spread_over_the_workspace(cfg: CellConfig) -> None:
    cell = timed_cell(cfg, 5, warmup=Warmup(), knock=Knock(at_s=HOUR_S))
    v = validation_positions(cell, 100, np.random.default_rng(0))
    assert len(v) == 100 and v.q_deg.shape == (100, 6) and v.p_part_mm.shape == (100, 3)
    truth = LineTruth(cell, v)
    c0 = truth.validation_centres_sensor_mm(0.0)
    assert np.all(cell.spec.volume.contains(c0))
    p_base = (v.p_part_mm - cfg.T_part_base[:3, 3]) @ cfg.T_part_base[:3, :3]
    r = np.hypot(p_base[:, 0], p_base[:, 1])
    azimuth_deg = np.degrees(np.arctan2(p_base[:, 1], p_base[:, 0]))
    assert r.min() >= 900.0 and r.max() <= 1900.0 and np.ptp(azimuth_deg) > 270.0
    # after the knock and 3 h of warm-up a perfect sensor sees every position elsewhere
    moved = np.linalg.norm(truth.validation_centres_sensor_mm(3 * HOUR_S) - c0, axis=1)
    assert np.all(moved > 0.05) and np.all(moved < 1.5)


def true_validation_rms_mm(cfg: CellConfig, truth: LineTruth, x: np.ndarray, t_s: float) -> float:
    """How the app computes the true error of parameters x at the validation positions."""
    v = truth.validation
    e = cfg.model().points_part(x, v.q_deg, truth.validation_centres_sensor_mm(t_s)) - v.p_part_mm
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_the_app_can_compute_the_true_error_of_identified_parameters_over_time(
    cfg: CellConfig,
) -> None:
    knock = Knock(at_s=2 * HOUR_S)
    cell = timed_cell(cfg, 6, warmup=Warmup(), knock=knock)  # the clock stands at sim 0
    model = cfg.model()
    x0 = model.nominal_x()
    cal = collect(cell, model, x0, cfg.spheres_part_mm, 6, np.random.default_rng(0))
    x = identify(model, cal.measurements).x
    truth = LineTruth(cell, validation_positions(cell, 100, np.random.default_rng(1)))
    calibrated = true_validation_rms_mm(cfg, truth, x, 0.0)
    assert true_validation_rms_mm(cfg, truth, x0, 0.0) > 5 * calibrated  # calibration helps
    assert calibrated < 0.15
    warm = true_validation_rms_mm(cfg, truth, x, knock.at_s - 1.0)
    knocked = true_validation_rms_mm(cfg, truth, x, knock.at_s)
    assert warm > calibrated  # the warm-up degrades the calibration of the cold cell ...
    assert knocked > warm + 0.1  # ... and the knock does, by about its 0.3 mm


def test_a_fixture_knock_moves_the_spheres_frame_about_their_centroid(cfg: CellConfig) -> None:
    """The part frame the spheres define moves 0.5 mm and turns 0.03 deg about the spheres'
    centroid: each sphere moves about 0.5 mm in the robot's world, the sensor mount not."""
    knock = Knock.of_kind("fixture", 2 * HOUR_S)
    assert (knock.shift_mm, knock.tilt_deg) == (0.5, 0.03)
    cell = timed_cell(cfg, 2, knock=knock)
    np.testing.assert_array_equal(cell.mount_at(knock.at_s), cell.mount_at(0.0))
    q = np.array([[10.0, 20.0, 0.0, 0.0, -70.0, 0.0]])
    before, after = cell.T_part_sensor(q, 0.0)[0], cell.T_part_sensor(q, knock.at_s)[0]
    moved = after @ np.linalg.inv(before)  # T_partAfter_partBefore, the same at every q
    assert rotation_deg(moved[:3, :3]) == pytest.approx(0.03, abs=1e-6)
    centroid = np.mean([cell.target_true_mm(t) for t in cell.target_ids()], axis=0)
    for tid in cell.target_ids():  # where a sphere of the old frame is seen in the new one
        p = cell.target_true_mm(tid)
        shift = np.linalg.norm(moved[:3, :3] @ p + moved[:3, 3] - p)
        lever = np.radians(0.03) * np.linalg.norm(p - centroid)
        assert abs(shift - 0.5) <= lever + 1e-6
    q2 = np.array([[-60.0, 10.0, 5.0, 20.0, -80.0, 30.0]])
    moved2 = cell.T_part_sensor(q2, knock.at_s)[0] @ np.linalg.inv(cell.T_part_sensor(q2, 0.0)[0])
    np.testing.assert_allclose(moved2, moved, atol=1e-9)


def test_a_joint_knock_slips_the_j2_zero_by_001_deg(cfg: CellConfig) -> None:
    knock = Knock.of_kind("joint", HOUR_S)
    cell = timed_cell(cfg, 3, knock=knock)
    np.testing.assert_array_equal(cell.mount_at(knock.at_s), cell.mount_at(0.0))
    q = np.array([[10.0, 20.0, 0.0, 0.0, -70.0, 0.0]])
    after = cell.T_part_sensor(q, knock.at_s)
    for sign in (1.0, -1.0):  # the same as commanding J2 0.01 deg further, one way or the other
        q2 = q + np.array([[0.0, sign * 0.01, 0.0, 0.0, 0.0, 0.0]])
        q2[0, 2] -= sign * 0.01  # the controller's J3 is relative to the horizon (q3 = J3 + J2)
        if np.allclose(cell.T_part_sensor(q2, 0.0), after, atol=1e-9):
            break
    else:
        pytest.fail("the J2 zero did not slip by 0.01 deg")
    with pytest.raises(ValueError, match="knock kind"):
        Knock(at_s=0.0, kind="base")
