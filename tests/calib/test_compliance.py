"""The compliance- and temperature-aware model: against the independent simulated robot,
its Jacobian, recovery of known compliance and expansion from noisy data, the rigid model
unchanged with the terms off, the redundancy check, and a rigid version carried into it
predicting the rigid version's points."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from app.config import CellConfig, load_cell
from app.sim.accuracy import WarmData, measure_views, plan_views, simulated_truth
from app.sim.cell import make_cell
from app.workspace import workspace_points
from calib import robot
from calib.compliance import (
    LENGTH_NAMES,
    CompliantModel,
    CompliantSettings,
    carry,
    select_model,
)
from calib.errors import NotIdentifiable
from calib.identify import Measurements, identify, residuals
from calib.model import EXTRA_NAMES, INDEX, PAPER_30, SystemModel, unit_of
from fakes.cell_spec import SimSettings
from fakes.truth import LINK_MASS_KG, TrueRobot

F = np.float64
TRUTH = simulated_truth()
#: the simulated robot's sensor mass and joint compliance: the configured payload
PAYLOAD = CompliantSettings(payload_kg=LINK_MASS_KG[2], nominal_compliance_rad_per_nm=5e-8)


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    lim = robot.JointLimits()
    return rng.uniform(lim.lower_deg, lim.upper_deg, (n, 6))


def true_x(model: CompliantModel) -> np.ndarray:
    x = model.nominal_x()
    for name, value in TRUTH.items():
        x[INDEX[name]] = value
    return x


@pytest.mark.parametrize("temp_c", [20.0, 34.0, 8.0])
def test_fk_equals_the_simulated_robot_with_compliance_and_growth(temp_c: float) -> None:
    q = random_q(np.random.default_rng(0), 2000)
    model = CompliantModel(np.eye(4), np.eye(4), settings=PAYLOAD)
    truth = TrueRobot(compliance_rad_per_nm=(5e-8, 5e-8), expansion_per_k=11.5e-6)
    T_model = model.fk(true_x(model), q, flange=True, temp_c=temp_c)
    T_true = truth.T_world_tool0(q, temp_c)
    # the truth deflects a second time from its deflected frames: ~1e-9 rad of difference
    assert np.abs(T_model[:, :3, 3] - T_true[:, :3, 3]).max() < 1e-5
    assert np.abs(T_model[:, :3, :3] - T_true[:, :3, :3]).max() < 1e-8
    rigid = TrueRobot().T_world_tool0(q, temp_c)
    assert np.abs(T_true[:, :3, 3] - rigid[:, :3, 3]).max() > 0.05  # the effect is real


def test_first_order_thermal_points_match_exact_growth() -> None:
    rng = np.random.default_rng(1)
    model = CompliantModel(np.eye(4), np.eye(4), settings=PAYLOAD)
    x, q = true_x(model), random_q(rng, 200)
    c = rng.normal([0, 0, 130], 10.0, (200, 3))
    exact = np.einsum("nij,nj->ni", model.fk(x, q, temp_c=40.0)[:, :3, :3], c)
    exact += model.fk(x, q, temp_c=40.0)[:, :3, 3]
    first = model.points_part(x, q, c, temp_c=np.full(200, 40.0))
    assert np.abs(first - exact).max() < 2e-4  # 20 K: second order only


STEP = {"mm": 1e-4, "rad": 1e-7, "rad/m": 1e-9, "1/K": 1e-10}


@pytest.mark.parametrize("with_temp", [False, True])
def test_jacobian_equals_central_differences(with_temp: bool) -> None:
    rng = np.random.default_rng(2)
    model = CompliantModel(np.eye(4), np.eye(4), settings=PAYLOAD)
    x, q = true_x(model), random_q(rng, 40)
    c = rng.normal([0, 0, 130], 10.0, (40, 3))
    temps = rng.uniform(15.0, 35.0, 40) if with_temp else None
    names = model.names if with_temp else model.names[:-1]
    J = model.point_jacobian(x, q, c, names, temp_c=temps).reshape(-1, len(names))
    for k, name in enumerate(names):
        h = STEP[unit_of(name)]
        xp, xm = x.copy(), x.copy()
        xp[k] += h
        xm[k] -= h
        fd = (model.points_part(xp, q, c, temps) - model.points_part(xm, q, c, temps)).ravel()
        rel = np.abs(J[:, k] - fd / (2 * h)).max() / np.linalg.norm(fd / (2 * h))
        # the extra columns are analytic (the compliance ones up to the thermal coupling);
        # the geometric ones leave out the second-order coupling through the levers
        exact = name == "expansion_per_k" or (name in EXTRA_NAMES and not with_temp)
        assert rel < (1e-6 if exact else 2e-4), (name, rel)


def test_rigid_model_is_unchanged_when_the_terms_are_off(cfg: CellConfig) -> None:
    from tests.conftest import simulated

    cal, val = simulated(0, 30)
    rigid = cfg.model()
    off = CompliantModel.of(rigid, CompliantSettings(expansion_per_k=0.0))
    r = identify(rigid, cal.measurements)
    c = identify(off, cal.measurements, active=PAPER_30)
    assert np.array_equal(r.x, c.x[: len(r.x)]) and np.array_equal(r.std, c.std)
    assert np.array_equal(
        residuals(rigid, r.x, val.measurements), residuals(off, c.x, val.measurements)
    )
    assert not np.any(c.x[len(r.x) :])


@cache
def warm_data(seed: int, n_points: int, n_each: int, noise: float) -> WarmData:
    """Views of the 4 spheres (or of n_points spread over the workspace) at 15..35 degC, with
    `noise` times the cell's robot repeatability, sensor and tracker noise."""
    cfg = load_cell(None)
    s = SimSettings()
    cell = make_cell(
        cfg,
        seed=seed,
        sensor_noise_mm=s.sensor_noise_mm * noise,
        tracker_noise_mm=s.tracker_noise_mm * noise,
        repeatability_mm=s.repeatability_mm * noise,
    )
    rng = np.random.default_rng([seed, 5])
    points = cfg.spheres_part_mm if n_points == 4 else workspace_points(cfg, n_points, rng)
    views = plan_views((cell,), cfg.model(), points, n_each, (15.0, 35.0), rng)
    return measure_views(cell, views)


def test_recovers_compliance_and_expansion_exactly_without_noise(cfg: CellConfig) -> None:
    model = CompliantModel.of(cfg.model(), PAYLOAD)
    result = identify(model, warm_data(7, 4, 8, 0.0).measured)
    assert "expansion_per_k" in result.active and result.observability.rank == 34
    assert result.rms_mm < 1e-4
    for name, true in TRUTH.items():
        assert result.value(name) == pytest.approx(true, rel=2e-3), name


@pytest.mark.parametrize(
    ("n_points", "n_each", "noise", "rel"),
    [
        # the cell's noise (the robot's RP 0.07 mm, 5 um sensor, 10 um tracker), 4 spheres: the
        # arm compliance is weakly determined one by one (std 20-50 %), the expansion well
        (4, 40, 1.0, {"c2_upper": 0.8, "c2_fore": 1.5, "c3_fore": 1.5, "expansion_per_k": 0.05}),
        # a quarter of that noise, 12 positions over the workspace
        (12, 10, 0.25, {"c2_upper": 0.2, "c2_fore": 0.5, "c3_fore": 0.4, "expansion_per_k": 0.02}),
    ],
)
def test_recovers_compliance_and_expansion_from_noisy_data(
    cfg: CellConfig, n_points: int, n_each: int, noise: float, rel: dict[str, float]
) -> None:
    model = CompliantModel.of(cfg.model(), PAYLOAD)
    data = warm_data(8, n_points, n_each, noise).measured
    result = identify(model, data)
    assert result.success and 0.5 < result.sigma_mm / (0.0224 * noise) < 1.5
    for name, true in TRUTH.items():
        value, std = result.value(name), result.std[result.active.index(name)]
        assert abs(value - true) < 4.0 * std, name  # the reported uncertainty is honest
        assert value == pytest.approx(true, rel=rel[name]), name
    # the model explains the data: the rigid one leaves several times the residual
    assert identify(cfg.model(), data).rms_mm > 2.0 * result.rms_mm


def test_expansion_without_a_temperature_spread_is_reported_not_identifiable(
    cfg: CellConfig,
) -> None:
    model = CompliantModel.of(cfg.model())
    m = warm_data(7, 4, 8, 0.0).measured
    warm = Measurements(m.q_deg, m.c_sensor_mm, m.p_part_mm, m.targets, np.full(len(m), 25.0))
    assert "expansion_per_k" not in model.default_active(warm.temp_c)
    with pytest.raises(NotIdentifiable) as err:
        identify(model, warm, active=(*model.default_active(), "expansion_per_k"))
    assert any("expansion_per_k" in g for g in err.value.groups)


def test_select_model() -> None:
    base = SystemModel(np.eye(4), np.eye(4))
    assert select_model("rigid", base).kind == "rigid"
    compliant = select_model("compliant", base, PAYLOAD)
    assert compliant.kind == "compliant" and len(compliant.nominal_x()) == 43
    assert compliant.nominal_x()[INDEX["c2_payload"]] == pytest.approx(5e-8 * 9.81 * 6.0)
    with pytest.raises(ValueError, match="unknown model 'elastic'"):
        select_model("elastic", base)
    with pytest.raises(ValueError, match="payload_kg"):
        CompliantSettings(payload_kg=-1.0)


#: how close a carried rigid version's points are to the rigid version's [mm]: 1 um (the
#: carry is exact to rounding, ~2e-12 mm; the growth about a calibration temperature away from
#: the reference differs from the growth about the reference by s(T_cal) - 1 relative, ~1e-5 mm)
CARRY_TOL_MM = 1e-3


@cache
def rigid_version() -> tuple[SystemModel, np.ndarray, float]:
    """(rigid model, a version identified on the warm cell's views, their mean temperature)."""
    rigid = load_cell(None).model()
    result = identify(rigid, warm_data(7, 4, 8, 0.0).measured)
    assert result.temp_c is not None and 20.0 < result.temp_c < 30.0
    return rigid, result.x, result.temp_c


def workspace_views(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """n configurations over the joint ranges and a sphere centre seen from each (sensor frame,
    about the standoff)."""
    rng = np.random.default_rng(38)
    return random_q(rng, n), rng.normal([0.0, 0.0, 130.0], 10.0, (n, 3))


@pytest.mark.parametrize("settings", [CompliantSettings(), PAYLOAD], ids=["default", "payload"])
@pytest.mark.parametrize("calibrated_at", ["warm", "reference", "cold"])
def test_a_carried_rigid_version_predicts_its_points_at_its_calibration_temperature(
    settings: CompliantSettings, calibrated_at: str
) -> None:
    """The rigid version's lengths are the arm's at its calibration temperature; carried into
    the compliant model (configured payload or not) at that temperature it maps the sphere
    centres the sensor measures at any configuration of the workspace, and at the views it
    was identified from, to the points the rigid version does."""
    rigid, x_rigid, warm_c = rigid_version()
    t_cal = {"warm": warm_c, "reference": settings.reference_temp_c, "cold": 12.0}[calibrated_at]
    compliant = CompliantModel.of(rigid, settings)
    q, c = workspace_views()
    m = warm_data(7, 4, 8, 0.0).measured
    q, c = np.vstack([q, m.q_deg]), np.vstack([c, m.c_sensor_mm])
    model, x = carry(compliant, rigid, x_rigid, t_cal)
    assert model is compliant
    p_rigid = rigid.points_part(x_rigid, q, c)
    p_carried = model.points_part(x, q, c, temp_c=np.full(len(q), t_cal))
    assert np.linalg.norm(p_carried - p_rigid, axis=1).max() < CARRY_TOL_MM
    p_exact = apply_all(model.fk(x, q, temp_c=t_cal), c)  # the exact growth, one temperature
    assert np.linalg.norm(p_exact - p_rigid, axis=1).max() < CARRY_TOL_MM


def apply_all(T: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.einsum("nij,nj->ni", T[:, :3, :3], c) + T[:, :3, 3]


@pytest.mark.parametrize("temp_c", [35.0, 15.0])
def test_a_carried_rigid_version_grows_by_the_temperature_difference_only(temp_c: float) -> None:
    """At another temperature T the carried version predicts the rigid version's arm grown by
    the expansion of T - T_cal: every arm length and the J2 height, not of T - T_ref."""
    rigid, x_rigid, t_cal = rigid_version()
    compliant = CompliantModel.of(rigid, PAYLOAD)
    q, c = workspace_views()
    x = compliant.carried(x_rigid, t_cal)
    p_carried = compliant.points_part(x, q, c, temp_c=np.full(len(q), temp_c))
    grown = PAYLOAD.expansion_per_k * (temp_c - t_cal)
    x_grown = x_rigid.copy()
    cols = [INDEX[n] for n in LENGTH_NAMES]
    x_grown[cols] *= 1.0 + grown
    x_grown[0:3] += rigid.T_part_base(x_rigid)[:3, 2] * robot.BASE_LINK_TO_WORLD_Z_MM * grown
    p_grown = rigid.points_part(x_grown, q, c)
    assert np.linalg.norm(p_carried - p_grown, axis=1).max() < CARRY_TOL_MM
    moved = np.linalg.norm(p_carried - rigid.points_part(x_rigid, q, c), axis=1).max()
    assert moved > 0.05  # the growth is there, ~10 K of it


def test_a_compliant_version_is_not_carried() -> None:
    rigid, x_rigid, _ = rigid_version()
    compliant = CompliantModel.of(rigid, PAYLOAD)
    x = compliant.carried(x_rigid, 25.0)
    np.testing.assert_array_equal(carry(compliant, compliant, x, 30.0)[1], x)
    np.testing.assert_array_equal(compliant.carried(x, 30.0), x)
    model, y = carry(rigid, compliant, x, 30.0)
    assert model is compliant and y is x  # a rigid target keeps a compliant version's compliance
    with pytest.raises(ValueError, match="expected 37 or 43 parameters"):
        compliant.carried(x_rigid[:30])
