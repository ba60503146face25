"""The simulated cell behaves like a real one: errors of an uncalibrated robot, a small
gravity compliance, thermal growth, noisy instruments, a bounded measuring volume."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import CellConfig
from app.sim.cell import make_cell
from fakes.cell_spec import NotVisible


def random_q(cfg: CellConfig, n: int, seed: int) -> np.ndarray:
    lim = cfg.limits
    q = np.random.default_rng(seed).uniform(lim.lower_deg, lim.upper_deg, (n, 6))
    q[:, 1:3] = np.random.default_rng(seed + 1).uniform(-40, 40, (n, 2))
    return q


def test_uncalibrated_error_like_a_real_robot(cfg: CellConfig) -> None:
    model = cfg.model()
    q = random_q(cfg, 500, 0)
    for seed in (0, 1, 2):
        cell = make_cell(cfg, seed=seed)
        c = np.array([0.0, 0.0, 130.0])
        T_true = cell.T_part_sensor(q)
        e = model.points_part(model.nominal_x(), q, c) - (T_true[:, :3, :3] @ c + T_true[:, :3, 3])
        rms = np.sqrt(np.mean(np.sum(e**2, axis=1)))
        assert 1.0 <= rms <= 3.5, (seed, rms)


def test_compliance_is_about_a_tenth_of_a_millimetre(cfg: CellConfig) -> None:
    q = random_q(cfg, 300, 3)
    stiff = make_cell(cfg, seed=0, compliance=False).T_part_sensor(q)[:, :3, 3]
    soft = make_cell(cfg, seed=0).T_part_sensor(q)[:, :3, 3]
    d = np.linalg.norm(soft - stiff, axis=1)
    assert 0.03 < d.max() < 0.3


def test_thermal_growth_moves_the_sensor(cfg: CellConfig) -> None:
    cell = make_cell(cfg, seed=0)
    q = random_q(cfg, 50, 4)
    before = cell.T_part_sensor(q)[:, :3, 3]
    cell.temp_c = 30.0
    after = cell.T_part_sensor(q)[:, :3, 3]
    d = np.linalg.norm(after - before, axis=1)
    assert 0.05 < np.median(d) < 0.5  # ~11.5 um/m/K over ~2 m and 10 K


def test_measurements_are_noisy_and_bounded(cfg: CellConfig) -> None:
    cell = make_cell(cfg, seed=0)
    p = cfg.spheres_part_mm["P1"]
    T = cell.T_part_sensor(np.zeros((1, 6)))[0]
    # a configuration that does not see the sphere
    with pytest.raises(NotVisible):
        cell.measure_point(np.zeros(6), p + 5000.0 * T[:3, 0])
    tracked = np.array([cell.track_point(p) for _ in range(400)])
    assert np.allclose(tracked.mean(axis=0), p, atol=0.003)
    assert np.allclose(tracked.std(axis=0), 0.01, rtol=0.2)
