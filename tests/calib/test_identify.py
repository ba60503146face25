"""Identification on the simulated cell: exact recovery, accuracy gain, redundancy reports,
robust loss."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from calib.errors import InsufficientData, NotIdentifiable
from calib.identify import Measurements, identify, posterior_result, residuals
from calib.model import PAPER_30
from calib.observability import observability
from calib.validation import ErrorStats
from tests.conftest import simulated


@pytest.mark.parametrize("seed", [11, 12])
def test_noise_free_rigid_cell_is_represented_exactly(cfg: CellConfig, seed: int) -> None:
    cal, val = simulated(
        seed,
        40,
        compliance=False,
        thermal=False,
        sensor_noise_mm=0.0,
        tracker_noise_mm=0.0,
        repeatability_mm=0.0,  # a robot that repeats exactly: the noise-free cell
    )
    model = cfg.model()
    result = identify(model, cal.measurements)
    assert result.success and result.observability.rank == 30
    e = np.linalg.norm(residuals(model, result.x, val.measurements), axis=1)
    assert e.max() <= 1e-6


def test_default_cell_gains_at_least_20x(cfg: CellConfig) -> None:
    cal, val = simulated(0, 100)
    model = cfg.model()
    before = ErrorStats.of(residuals(model, model.nominal_x(), val.measurements))
    result = identify(model, cal.measurements)
    after = ErrorStats.of(residuals(model, result.x, val.measurements))
    assert 1.0 <= before.rmse_mm <= 3.0  # like an uncalibrated industrial robot
    assert before.rmse_mm / after.rmse_mm >= 20.0
    # the reported uncertainty is honest: parameter std small, residual sigma near the noise
    assert 0.01 < result.sigma_mm < 0.1
    assert np.all(np.isfinite(result.std)) and np.all(np.abs(np.diag(result.corr) - 1) < 1e-9)


def test_inputs_are_not_mutated(cfg: CellConfig) -> None:
    cal, _ = simulated(0, 100)
    m = cal.measurements
    copies = [m.q_deg.copy(), m.c_sensor_mm.copy(), m.p_part_mm.copy()]
    x0 = cfg.model().nominal_x()
    x0_copy = x0.copy()
    identify(cfg.model(), m, x0=x0)
    for a, b in zip((m.q_deg, m.c_sensor_mm, m.p_part_mm), copies, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(x0, x0_copy)


def test_papers_24_random_configurations_have_rank_30(cfg: CellConfig) -> None:
    cal, _ = simulated(0, 100)
    assert len(cal.measurements) == 24
    model = cfg.model()
    m = cal.measurements
    J = model.point_jacobian(model.nominal_x(), m.q_deg, m.c_sensor_mm, PAPER_30)
    obs = observability(J.reshape(-1, 30), 24)
    assert obs.rank == 30 and obs.condition < 1e3
    assert 0 < obs.indices["O1"] <= 1 / np.sqrt(24)


def test_d3_is_reported_redundant_with_its_partners(cfg: CellConfig) -> None:
    cal, _ = simulated(0, 100)
    with pytest.raises(NotIdentifiable) as info:
        identify(cfg.model(), cal.measurements, active=(*PAPER_30, "d3"))
    assert info.value.rank == 30 and info.value.n_params == 31
    (group,) = info.value.groups
    assert set(group) == {"d3", "d2"}  # both slide along the parallel J2/J3 axes
    assert "d3" in str(info.value)


def test_one_configuration_per_sphere_is_degenerate(cfg: CellConfig) -> None:
    cal, _ = simulated(0, 100)
    m = cal.measurements
    first = [m.targets.index(t) for t in sorted(set(m.targets))]
    rows = np.repeat(first, 6)  # every measurement of a sphere from one configuration
    degenerate = m.subset(rows)
    with pytest.raises(NotIdentifiable) as info:
        identify(cfg.model(), degenerate)
    assert info.value.rank < 30 and info.value.groups


def test_too_few_measurements(cfg: CellConfig) -> None:
    cal, _ = simulated(0, 100)
    with pytest.raises(InsufficientData, match="at least 10 measurements"):
        identify(cfg.model(), cal.measurements.subset(np.arange(9)))


def test_robust_loss_beats_least_squares_on_outliers(cfg: CellConfig) -> None:
    cal, val = simulated(0, 100)
    m = cal.measurements
    c = m.c_sensor_mm.copy()
    c[[2, 9, 17]] += [[3.0, 0.0, 0.0], [0.0, -2.5, 0.0], [0.0, 0.0, 4.0]]  # bad sphere fits
    bad = Measurements(m.q_deg, c, m.p_part_mm, m.targets)
    model = cfg.model()
    plain = identify(model, bad)
    robust = identify(model, bad, loss="soft_l1", f_scale_mm=0.05)
    e_plain = ErrorStats.of(residuals(model, plain.x, val.measurements)).rmse_mm
    e_robust = ErrorStats.of(residuals(model, robust.x, val.measurements)).rmse_mm
    assert e_robust < 0.5 * e_plain
    # the outliers stand out in the robust residuals
    worst = np.argsort(-np.linalg.norm(robust.residuals_mm, axis=1))[:3]
    assert set(worst) == {2, 9, 17}


def test_a_posterior_is_an_identification_outcome_with_its_own_covariance(
    cfg: CellConfig,
) -> None:
    """The in-line estimator's posterior as a recalibration's candidate: its x and covariance
    as given, its residuals and RMS on the data the gates read, and no rank asked of data it
    need not determine alone (the prior holds the rest)."""
    cal, _ = simulated(0, 100)
    m, model = cal.measurements, cfg.model()
    fit = identify(model, m)
    cov = np.diag(np.linspace(1e-4, 4e-4, len(fit.active)))
    got = posterior_result(model, m, fit.x, fit.active, cov, model.nominal_x())
    np.testing.assert_array_equal(got.x, fit.x)
    np.testing.assert_allclose(got.std, np.sqrt(np.diag(cov)))
    np.testing.assert_allclose(got.corr, np.eye(len(fit.active)), atol=1e-12)
    assert got.rms_mm == pytest.approx(fit.rms_mm) and got.success
    np.testing.assert_allclose(got.residuals_mm, residuals(model, fit.x, m))
    first = [m.targets.index(t) for t in sorted(set(m.targets))]
    degenerate = m.subset(np.repeat(first, 6))  # identify would refuse these alone
    alone = posterior_result(model, degenerate, fit.x, fit.active, cov, model.nominal_x())
    assert alone.observability.rank < len(fit.active)
    with pytest.raises(ValueError):
        posterior_result(model, m, fit.x, fit.active, cov[:-1, :-1], model.nominal_x())
