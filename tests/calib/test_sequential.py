"""The sequential (Kalman / RLS) estimator on the simulated cell: it reaches the batch
solution, its gate rejects outliers, process noise lets it follow a knock, and with the
compliant model it tracks a warming cell."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from app.sim.accuracy import measure_views, plan_views, simulated_truth
from app.sim.cell import DataSet, make_cell
from app.workspace import workspace_points
from calib import candidates
from calib.compliance import CompliantModel, CompliantSettings
from calib.errors import InsufficientData
from calib.identify import Measurements, identify, residuals
from calib.model import INDEX, SystemModel
from calib.sequential import SequentialEstimator, SequentialSettings
from calib.transforms import apply, inverse
from fakes.cell import SimulatedCell
from tests.conftest import simulated


def rmse(model: SystemModel, x: np.ndarray, data: Measurements) -> float:
    return float(np.sqrt(np.mean(np.sum(residuals(model, x, data) ** 2, axis=1))))


def truth_of(ds: DataSet) -> Measurements:
    m = ds.measurements
    return Measurements(m.q_deg, ds.truth_c_sensor_mm, ds.truth_p_part_mm, m.targets)


def feed(est: SequentialEstimator, m: Measurements) -> list[bool]:
    temps = [None] * len(m) if m.temp_c is None else list(m.temp_c)
    return [
        est.update(m.q_deg[i], m.c_sensor_mm[i], m.p_part_mm[i], temps[i]).accepted
        for i in range(len(m))
    ]


def test_one_pass_from_the_nominal_reaches_the_batch_solution(cfg: CellConfig) -> None:
    cal, val = simulated(21, 40, compliance=False, thermal=False)
    model = cfg.model()
    batch = identify(model, cal.measurements)
    est = SequentialEstimator.from_prior(model, model.nominal_x(), batch.active)
    assert all(feed(est, cal.measurements))
    before = rmse(model, model.nominal_x(), truth_of(val))
    after, reference = rmse(model, est.x, truth_of(val)), rmse(model, batch.x, truth_of(val))
    assert before > 1.0 and after < 1.3 * reference
    assert est.n_accepted == len(cal.measurements) and est.n_rejected == 0
    # the covariance agrees with the batch uncertainty (same data, weak prior)
    ratio = est.std / batch.std
    assert np.median(ratio) == pytest.approx(0.0224 / batch.sigma_mm, rel=0.35)


def test_gate_rejects_an_outlier_and_leaves_the_estimate(cfg: CellConfig) -> None:
    cal, _ = simulated(22, 10, compliance=False, thermal=False)
    model = cfg.model()
    est = SequentialEstimator.from_result(model, identify(model, cal.measurements))
    m = cal.measurements
    x_before, P_before = est.x, est.covariance
    bad = est.update(m.q_deg[0], m.c_sensor_mm[0] + [0.0, 0.0, 0.5], m.p_part_mm[0])
    assert not bad.accepted and bad.mahalanobis2 > 16.266 and est.n_rejected == 1
    assert np.array_equal(est.x, x_before) and np.array_equal(est.covariance, P_before)
    good = est.update(m.q_deg[1], m.c_sensor_mm[1], m.p_part_mm[1])
    assert good.accepted and good.mahalanobis2 < 16.266
    assert np.linalg.norm(good.innovation_mm) < 0.1


def stream(cell: SimulatedCell, cfg: CellConfig, n: int, seed: int) -> Measurements:
    rng = np.random.default_rng([seed, 9])
    points = workspace_points(cfg, n, rng)
    views = plan_views((cell,), cfg.model(), points, 1, (20.0, 20.0), rng)
    return measure_views(cell, views).measured


def test_a_knock_is_recognised_and_followed(cfg: CellConfig) -> None:
    model = cfg.model()
    cell = make_cell(cfg, seed=23, compliance=False, thermal=False)
    cal, _ = simulated(23, 10, compliance=False, thermal=False)
    start = identify(model, cal.measurements)
    drift = SequentialSettings(drift_mm=0.002, drift_rad=2e-6)
    ests = {
        "drift": SequentialEstimator.from_result(model, start, drift),
        "none": SequentialEstimator.from_result(model, start, SequentialSettings(knock_after=0)),
    }
    # a knock: the part frame moves by 0.3 mm and 0.2 mrad
    cell.T_part_world = cell.T_part_world.copy()
    cell.T_part_world[:3, 3] += [0.2, -0.2, 0.1]
    c, s = np.cos(2e-4), np.sin(2e-4)
    cell.T_part_world[:3, :3] = cell.T_part_world[:3, :3] @ np.array(
        [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    )
    after = stream(cell, cfg, 80, 1)
    check = stream(cell, cfg, 40, 2)
    errors = {}
    for name, est in ests.items():
        accepted = feed(est, after)
        errors[name] = rmse(model, est.x, check)
        if name == "drift":  # a few rejections, then the knock is recognised
            assert ests[name].n_knocks >= 1 and sum(accepted) >= 0.8 * len(after)
            assert not any(accepted[:5])
    stale = rmse(model, start.x, check)
    assert stale > 0.25 and errors["drift"] < 0.08  # near the noise of the check set
    assert errors["drift"] < 0.7 * errors["none"]


def test_compliant_estimator_tracks_a_warming_cell(cfg: CellConfig) -> None:
    model = CompliantModel.of(cfg.model(), CompliantSettings(expansion_per_k=0.0))
    cell = make_cell(cfg, seed=24)
    rng = np.random.default_rng([24, 3])
    views = plan_views((cell,), cfg.model(), cfg.spheres_part_mm, 20, (20.0, 35.0), rng)
    views.sort(key=lambda v: v.temp_c)  # the cell warms up while the line measures
    data = measure_views(cell, views).measured
    active = model.default_active(data.temp_c)
    assert "expansion_per_k" in active
    est = SequentialEstimator.from_prior(model, model.nominal_x(), active)
    assert sum(feed(est, data)) >= len(data) - 2
    true = simulated_truth()["expansion_per_k"]
    k = active.index("expansion_per_k")
    assert abs(est.x[INDEX["expansion_per_k"]] - true) < max(4.0 * est.std[k], 0.05 * true)


def test_bad_shapes_are_refused(cfg: CellConfig) -> None:
    model = cfg.model()
    with pytest.raises(InsufficientData, match="P0"):
        SequentialEstimator(model, model.nominal_x(), ("a1", "a2"), np.eye(3))
    with pytest.raises(ValueError, match="unknown model parameters: c2_upper"):
        SequentialEstimator(model, model.nominal_x(), ("c2_upper",), np.eye(1))
    with pytest.raises(ValueError, match="drift"):
        SequentialSettings(drift_mm=-1.0)


def test_adaptive_scheduling_gains_more_information_than_cycling(cfg: CellConfig) -> None:
    model = cfg.model()
    cell = make_cell(cfg, seed=25, compliance=False, thermal=False)
    cal, _ = simulated(25, 10, compliance=False, thermal=False)
    start = identify(model, cal.measurements.subset(np.arange(0, 24, 2)))  # 12 measurements
    rng = np.random.default_rng(25)
    pool = []  # (q, sphere) views the cell sees, the centre expected from the estimate
    for p in cfg.spheres_part_mm.values():
        tracked = cell.track_point(p)
        for q in candidates.random_configurations(model, start.x, p, 15, rng).q_deg:
            if cell.sees(q, p):
                pool.append((q, p, tracked))
    q_pool = np.array([v[0] for v in pool])
    # the plan cycled: one view of each sphere in turn
    sphere_of = [
        int(np.argmin([np.linalg.norm(v[1] - p) for p in cfg.spheres_part_mm.values()]))
        for v in pool
    ]
    rank_in_sphere = [sphere_of[:i].count(sphere_of[i]) for i in range(len(pool))]
    cycle = np.lexsort((sphere_of, rank_in_sphere))
    ests = {k: SequentialEstimator.from_result(model, start) for k in ("adaptive", "cycle")}
    for step in range(24):
        for name, est in ests.items():
            T_sp = inverse(model.fk(est.x, q_pool))
            c_pool = apply(T_sp, np.array([v[1] for v in pool]))
            gains = est.information_gain(q_pool, c_pool)
            k = est.choose_next(q_pool, c_pool) if name == "adaptive" else int(cycle[step])
            assert name == "cycle" or gains[k] == gains.max()
            q, p, tracked = pool[k]
            assert est.update(q, cell.measure_point(q, p), tracked).accepted
    logdet = {k: np.linalg.slogdet(e.covariance)[1] for k, e in ests.items()}
    # greedy D-optimal choice: a 7x smaller uncertainty volume for the same number of updates
    assert logdet["adaptive"] < logdet["cycle"] - 2.0, logdet
