"""The one end-to-end truth (app/sim/truth.py) against what the renderer and vision measure."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from app.config.line import SweepSettings
from app.sim.cell import scaled_sensor_model, simulated_sets, true_sensor_model
from app.sim.cold_calibration import as_the_line_measures
from app.sim.truth import EndToEndTruth, observe
from calib.model import INDEX
from fakes.render import render_sphere_sweep
from fakes.render_sensor import default_true_sensor
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import SensorModel

COMMANDS_V = np.array(SweepSettings().commands_v())
TRUE = default_true_sensor()


def scaled_model(focal_scale: float, cx_shift_px: float = 0.0) -> SensorModel:
    """The true sensor's model with a known calibration error."""
    return scaled_sensor_model(true_sensor_model(TRUE), focal_scale, cx_shift_px)


CENTRES_MM = [np.array([0.0, 0.0, 130.0]), np.array([7.0, -9.0, 127.0])]


@pytest.mark.parametrize("c_true", CENTRES_MM)
def test_a_perfect_sensor_model_reports_the_true_centre(c_true: np.ndarray) -> None:
    seen = observe(TRUE, true_sensor_model(TRUE), c_true, COMMANDS_V)
    assert seen.c_sensor_mm is not None
    assert np.abs(seen.c_sensor_mm - c_true).max() < 0.5e-3  # the stripe sampling: < 0.5 um


@pytest.mark.parametrize("c_true", CENTRES_MM)
def test_the_truth_equals_a_rendered_measurement_within_its_noise(c_true: np.ndarray) -> None:
    """A sensor model 0.1 % off in focal length and 2 px in the principal point: the truth's
    centre is the rendered measurement's (mean of 3 sweeps) within a few micrometres, while both
    are tens of micrometres from the true centre."""
    model = scaled_model(1.001, 2.0)
    seen = observe(TRUE, model, c_true, COMMANDS_V)
    assert seen.c_sensor_mm is not None
    rng = np.random.default_rng(5)
    rendered = []
    for _ in range(3):
        frames, cmds, _ = render_sphere_sweep(c_true, 15.0, TRUE, rng, commands_v=COMMANDS_V)
        rendered.append(measure_sphere_from_sweep(frames, cmds, model).c_sensor_mm)
    mean = np.mean(rendered, axis=0)
    assert np.linalg.norm(seen.c_sensor_mm - c_true) > 0.05  # the model's error is visible
    assert np.abs(seen.c_sensor_mm - mean).max() < 4e-3


def test_the_cached_correction_follows_a_moved_centre() -> None:
    """A view whose true centre moved less than refresh_mm keeps its correction: within 0.5 um
    of a fresh computation; a larger move computes it again."""
    model = scaled_model(1.001, 2.0)
    truth = EndToEndTruth(TRUE, model, tuple(COMMANDS_V))
    c0 = np.array([[3.0, 4.0, 129.0]])
    truth.centres(c0)
    moved = c0 + np.array([[0.15, -0.1, 0.1]])
    cached, ok = truth.centres(moved)
    fresh = observe(TRUE, model, moved[0], COMMANDS_V).c_sensor_mm
    assert ok[0] and fresh is not None
    assert np.abs(cached[0] - fresh).max() < 0.5e-3
    far = c0 + np.array([[2.0, 0.0, 0.0]])
    again, _ = truth.centres(far)
    fresh_far = observe(TRUE, model, far[0], COMMANDS_V).c_sensor_mm
    assert fresh_far is not None and np.allclose(again[0], fresh_far, atol=1e-9)


def test_the_geometric_path_is_the_kinematic_error(cfg: CellConfig) -> None:
    """Without a sensor model the measured centre is the true one: the error is the parameters'
    alone. Known: parameters whose part->base x is 0.3 mm off report every point 0.3 mm off
    in the part frame's x; true points moved by a known offset show it with the opposite sign."""
    model = cfg.model()
    x = model.nominal_x()
    rng = np.random.default_rng(2)
    q = rng.uniform(-30, 30, (5, 6))
    c = rng.uniform(-5, 5, (5, 3)) + np.array([0.0, 0.0, 130.0])
    offset = rng.normal(0, 0.1, (5, 3))
    p_true = model.points_part(x, q, c) + offset
    truth = EndToEndTruth(TRUE, None, tuple(COMMANDS_V))
    assert truth.kinematic_only
    x_off = x.copy()
    x_off[INDEX["x_PB"]] += 0.3
    e = truth.errors_mm(model, x_off, q, c, p_true)
    np.testing.assert_allclose(e, np.array([0.3, 0.0, 0.0]) - offset, atol=1e-9)
    assert truth.rmse_mm(model, x, q, c, p_true) == pytest.approx(
        np.sqrt(np.mean(np.sum(offset**2, axis=1)))
    )


def test_through_a_sensor_model_the_error_is_the_rendered_measurements(cfg: CellConfig) -> None:
    """With the true parameters the part-frame error of a view is the sensor model's alone: as
    long as the rendered measurement's error of the centre (the renderer knows the true sphere;
    the parameters map it with a rigid motion), tens of micrometres here; a view out of the field
    of view is left out."""
    model = cfg.model()
    x = model.nominal_x()
    sensor_model = scaled_model(1.001, 2.0)
    c_true = np.array([*CENTRES_MM, np.array([0.0, 30.0, 130.0])])
    q = np.array([[0.0, 10.0, -10.0, 0.0, -80.0, 0.0], [20.0, 0.0, 5.0, 30.0, -60.0, 10.0]] * 2)
    q = q[: len(c_true)]
    p_true = model.points_part(x, q, c_true)
    truth = EndToEndTruth(TRUE, sensor_model, tuple(COMMANDS_V))
    e = truth.errors_mm(model, x, q, c_true, p_true)
    assert e.shape == (2, 3) and list(truth.rejected()) == [2]
    rng = np.random.default_rng(5)
    for k, c in enumerate(CENTRES_MM):
        rendered = [
            measure_sphere_from_sweep(
                *render_sphere_sweep(c, 15.0, TRUE, rng, commands_v=COMMANDS_V)[:2], sensor_model
            ).c_sensor_mm
            for _ in range(3)
        ]
        seen_mm = float(np.linalg.norm(np.mean(rendered, axis=0) - c))
        assert seen_mm > 0.05  # the sensor model's error is visible
        assert abs(float(np.linalg.norm(e[k])) - seen_mm) < 4e-3


def test_a_view_the_vision_rejects_is_left_out_and_named() -> None:
    """A sphere out of the field of view gives too few stripe points, as on the line."""
    truth = EndToEndTruth(TRUE, true_sensor_model(TRUE), tuple(COMMANDS_V))
    c = np.array([[0.0, 0.0, 130.0], [0.0, 30.0, 130.0]])
    _, ok = truth.centres(c)
    assert ok.tolist() == [True, False]
    assert list(truth.rejected()) == [1]


def test_a_view_the_vision_rejects_is_left_out_of_the_line_measured_set(cfg: CellConfig) -> None:
    """`as_the_line_measures` with a truth that rejects a view (its centre NaN): the other views
    measured, shifted by what the sensor model reports, never a NaN in the set (a sensor
    replaced and calibrated anew had a view of the cold cell's commissioning rejected and the
    simulated line stopped at its start with "holds a NaN")."""
    sets = simulated_sets(cfg, 3, n_each=2, n_validation=1)
    c_true = sets.calibration.truth_c_sensor_mm
    shift = np.array([0.01, -0.02, 0.03])

    class Rejecting:
        kinematic_only = False

        def centres(self, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            ok = np.arange(len(c)) != 1
            return np.where(ok[:, None], c + shift, np.nan), ok

    got = as_the_line_measures(sets.calibration, Rejecting())  # type: ignore[arg-type]
    data = sets.calibration.measurements
    keep = [k for k in range(len(c_true)) if k != 1]
    assert np.isfinite(got.c_sensor_mm).all() and len(got.c_sensor_mm) == len(keep)
    assert np.allclose(got.c_sensor_mm, data.c_sensor_mm[keep] + shift)
    assert np.array_equal(got.q_deg, data.q_deg[keep])
