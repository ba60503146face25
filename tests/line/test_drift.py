"""Drift charts: a step of known size is flagged within the samples the REFERENCE.md figures
give, an in-control stream rarely signals, and the residual uses the model."""

from __future__ import annotations

import numpy as np

from app.config import load_cell
from app.line.drift import OVERALL, DriftMonitor, residual_mm
from app.line.settings import DriftSettings

MU, SIGMA = 0.05, 0.01


def _delay(step_sigma: float, rng: np.random.Generator, n_before: int = 30) -> int:
    """Samples after the step until the first signal of the overall chart."""
    mon = DriftMonitor(DriftSettings(baseline_n=30))
    for e in rng.normal(MU, SIGMA, 30 + n_before):
        mon.update("P1", float(e))
    for k in range(1, 200):
        sigs = mon.update("P1", float(rng.normal(MU + step_sigma * SIGMA, SIGMA)))
        if any(s.stream == OVERALL for s in sigs):
            return k
    return 200


def test_a_3_sigma_step_is_flagged_in_2_to_3_samples() -> None:
    rng = np.random.default_rng(1)
    delays = [_delay(3.0, rng) for _ in range(100)]
    assert 1 <= np.median(delays) <= 3
    assert np.percentile(delays, 90) <= 5


def test_a_1_sigma_step_is_flagged_in_about_10_samples() -> None:
    rng = np.random.default_rng(2)
    delays = [_delay(1.0, rng) for _ in range(100)]
    assert 4 <= np.median(delays) <= 14


def test_in_control_streams_rarely_signal_and_reset_relearns() -> None:
    rng = np.random.default_rng(3)
    false = 0
    for _ in range(50):
        mon = DriftMonitor(DriftSettings(baseline_n=30))
        false += any(mon.update("P1", float(e)) for e in rng.normal(MU, SIGMA, 130))
    assert false <= 10  # 50 runs of 100 watched samples each
    mon = DriftMonitor(DriftSettings(baseline_n=8))
    for e in rng.normal(MU, SIGMA, 8):
        mon.update("P2", float(e))
    assert mon.update("P2", 1.0) and mon.drifting  # a knock of 100 sigma: at once
    assert mon.update("P2", 1.0) == []  # signals once
    mon.reset()
    assert not mon.drifting and mon.update("P2", 1.0) == []  # learning the new baseline


def test_residual_is_the_distance_to_the_known_sphere() -> None:
    model = load_cell(None).model()
    x = model.nominal_x()
    q = np.array([10.0, 5.0, -5.0, 0.0, -80.0, 0.0])
    c = np.array([1.0, -2.0, 130.0])
    p = model.points_part(x, q[None], c[None])[0]
    assert residual_mm(model, x, q, c, p) < 1e-9
    assert abs(residual_mm(model, x, q, c, p + np.array([0.0, 0.3, 0.4])) - 0.5) < 1e-9
