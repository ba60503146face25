"""On the simulated cell, the compensated targets bring the true robot from the nominal error
level to the calibrated one (the table in docs/results/compensation.md, on one seed)."""

from __future__ import annotations

import numpy as np

from app.config import load_cell
from app.sim.compensation import CASES, run_seed


def rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v**2)))


def test_true_pose_error_drops_to_the_calibrated_level_over_100_poses() -> None:
    r = run_seed(load_cell(None), seed=2, n_poses=100)
    assert r.n_refused == 0
    e = r.errors
    assert all(len(e[k].position_mm) == 100 for k in CASES)
    nominal, compensated = e["nominal"], e["compensated"]
    assert rms(nominal.standoff_mm) > 1.0  # the uncalibrated robot misses by millimetres
    assert rms(compensated.standoff_mm) < 0.1
    assert rms(compensated.standoff_mm) < 0.05 * rms(nominal.standoff_mm)
    assert rms(compensated.position_mm) < 0.3 * rms(nominal.position_mm)
    assert rms(compensated.rotation_mrad) < rms(nominal.rotation_mrad)
    # the compensation adds nothing to the identified model's own error
    level = e["calibrated level"]
    assert abs(rms(compensated.standoff_mm) - rms(level.standoff_mm)) < 0.005
    # 3 decimals in the .ls file cost micrometres
    rounded = e["compensated, .ls 3 decimals"]
    assert abs(rms(rounded.standoff_mm) - rms(compensated.standoff_mm)) < 0.01
