"""The sensor's acceptance test (vision/acceptance.py) on rendered sweeps with a known truth: a
sphere at the 9 positions of app/commission/acceptance.py, seen by the true sensor, measured
with the true model (passes) and with a model whose scale is 0.1 % off (fails PS and SD)."""

from __future__ import annotations

import numpy as np
import pytest

from app.commission.acceptance import volume_positions
from app.config import load_cell
from app.config.line import SweepSettings
from app.sim.cell import scaled_sensor_model, true_sensor_model
from fakes.render import render_sphere_sweep
from fakes.render_sensor import default_true_sensor
from vision.acceptance import Acceptance, AcceptanceLimits, acceptance, spacing_errors
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import SensorModel

TRUE = default_true_sensor()
RADIUS_MM = 15.0
S = load_cell(None).sensor
LIMITS = AcceptanceLimits(S.max_pf_mm, S.max_ps_mm, S.max_sd_mm)


def _accept(model: SensorModel) -> Acceptance:
    """The sphere fixed at p in a reference frame; the sensor translated so that it appears at
    each position (T_ref_sensor = translation p - c)."""
    rng = np.random.default_rng(3)
    cmds = np.array(SweepSettings().commands_v())
    p = np.array([100.0, -50.0, 400.0])
    form, radius, centres, poses = [], [], [], []
    for c in volume_positions(S):
        frames, cm, _ = render_sphere_sweep(c, RADIUS_MM, TRUE, rng, commands_v=cmds)
        m = measure_sphere_from_sweep(frames, cm, model)
        form.append(m.quality.form_mm)
        radius.append(m.quality.radius_free_mm)
        centres.append(m.c_sensor_mm)
        T = np.eye(4)
        T[:3, 3] = p - c
        poses.append(T)
    return acceptance(
        np.array(form), np.array(radius), RADIUS_MM, np.array(centres), np.array(poses), LIMITS
    )


@pytest.fixture(scope="module")
def with_truth() -> Acceptance:
    return _accept(true_sensor_model(TRUE))


def test_the_true_sensor_model_passes(with_truth: Acceptance) -> None:
    acc = with_truth
    assert acc.passed, acc.message
    assert len(acc.pf_mm) == len(acc.ps_mm) == 9 and len(acc.sd_mm) == 36
    assert 0.03 < acc.figures["PF"] < LIMITS.pf_mm  # the speckle's range, not zero
    assert abs(acc.figures["PS"]) < 0.5 * LIMITS.ps_mm
    assert abs(acc.figures["SD"]) < 0.5 * LIMITS.sd_mm


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_a_sensor_model_with_a_scale_error_of_0_1_percent_fails() -> None:
    acc = _accept(scaled_sensor_model(true_sensor_model(TRUE), 1.001))
    assert not acc.passed
    assert not acc.passed_each["PS"] and not acc.passed_each["SD"]
    assert acc.figures["PS"] < -LIMITS.ps_mm  # the sphere measured smaller
    assert "beyond" in acc.message


def test_spacing_errors_of_exact_centres_are_zero_and_see_a_scale() -> None:
    rng = np.random.default_rng(1)
    c = rng.uniform(-10, 10, (5, 3)) + np.array([0.0, 0.0, 130.0])
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    p = np.array([5.0, 6.0, 7.0])
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p - c @ R.T  # each pose puts p at c
    pairs, sd = spacing_errors(c, T)
    assert pairs.shape == (10, 2) and np.abs(sd).max() < 1e-9
    _, sd_scaled = spacing_errors(1.001 * c, T)
    d = np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1)
    np.testing.assert_allclose(sd_scaled, 0.001 * d, atol=1e-6)
    with pytest.raises(ValueError, match="3 centres but 5 poses"):
        spacing_errors(c[:3], T)


def test_the_figures_are_the_worst_position_or_pair_and_say_so() -> None:
    """PF is the largest of the positions' ranges (written without a sign, its limit without
    "+-"), PS the largest |PS| and SD the largest |SD| of the pairs; `worst` finds them."""
    pairs = np.column_stack(np.triu_indices(4, k=1)).astype(np.intp)
    acc = Acceptance(
        np.array([0.08, 0.11, 0.09, 0.1]),
        np.array([0.004, -0.012, 0.01, 0.0]),
        np.array([0.002, -0.003, 0.001, 0.009, -0.004, 0.0]),
        pairs,
        AcceptanceLimits(0.15, 0.025, 0.015),
    )
    assert [acc.worst(k) for k in ("PF", "PS", "SD")] == [1, 1, 3]
    assert tuple(acc.pairs[acc.worst("SD")]) == (1, 2)
    assert acc.figures == {"PF": 0.11, "PS": -0.012, "SD": 0.009}
    assert acc.message == (
        "PF 110.0 um, the largest of 4 positions' ranges, within 150.0 um; "
        "PS -12.0 um, the largest |PS| of 4 positions, within +-25.0 um; "
        "SD +9.0 um, the largest |SD| of 6 pairs, within +-15.0 um"
    )
