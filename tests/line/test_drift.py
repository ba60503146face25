"""Drift charts: a step of known size is flagged within the samples the REFERENCE.md figures
give, an in-control stream rarely signals, the change point is estimated, a seeded chart watches
from its first sample, the change charts keep their baseline across an apply, and the residual
uses the model."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import load_cell
from app.config.line import DriftSettings
from app.line.drift import OVERALL, DriftMonitor, prediction_inflation, residual_mm

MU, SIGMA = 0.05, 0.01


def _delay(step_sigma: float, rng: np.random.Generator, n_before: int = 30) -> int:
    """Samples after the step until the first signal of the overall chart."""
    mon = DriftMonitor(DriftSettings(baseline_n=30))
    for i, e in enumerate(rng.normal(MU, SIGMA, 30 + n_before)):
        mon.update("P1", float(e), i)
    for k in range(1, 200):
        sigs = mon.update("P1", float(rng.normal(MU + step_sigma * SIGMA, SIGMA)), 1000 + k)
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
        false += any(
            mon.update("P1", float(e), i) for i, e in enumerate(rng.normal(MU, SIGMA, 130))
        )
    assert false <= 10  # 50 runs of 100 watched samples each
    mon = DriftMonitor(DriftSettings(baseline_n=8))
    for i, e in enumerate(rng.normal(MU, SIGMA, 8)):
        mon.update("P2", float(e), i)
    assert mon.update("P2", 1.0, 8) and mon.drifting  # a knock of 100 sigma: at once
    assert mon.update("P2", 1.0, 9) == []  # signals once
    mon.reset()
    assert not mon.drifting and mon.update("P2", 1.0, 10) == []  # learning the new baseline


def test_residual_is_the_distance_to_the_known_sphere() -> None:
    model = load_cell(None).model()
    x = model.nominal_x()
    q = np.array([10.0, 5.0, -5.0, 0.0, -80.0, 0.0])
    c = np.array([1.0, -2.0, 130.0])
    p = model.points_part(x, q[None], c[None])[0]
    assert residual_mm(model, x, q, c, p) < 1e-9
    assert abs(residual_mm(model, x, q, c, p + np.array([0.0, 0.3, 0.4])) - 0.5) < 1e-9


def test_the_change_point_is_the_first_sample_after_the_step() -> None:
    rng = np.random.default_rng(5)
    mon = DriftMonitor(DriftSettings(baseline_n=20))
    for i, e in enumerate(rng.normal(MU, SIGMA, 60)):
        mon.update("P1", float(e), i)
    signals = []
    for i in range(60, 80):
        signals += mon.update("P1", float(rng.normal(MU + 2 * SIGMA, SIGMA)), i)
    # the CUSUM's estimate: at the step (60) or a few samples around it for a 2-sigma step
    assert signals and all(52 <= s.onset_ref <= 62 for s in signals), signals
    big = DriftMonitor(DriftSettings(baseline_n=20))
    for i in range(60):
        big.update("P1", MU + SIGMA * (-1) ** i, i)
    assert big.update("P1", MU + 30 * SIGMA, 60)[0].onset_ref == 60  # a knock: exact


def test_a_seeded_residual_chart_watches_from_its_first_sample() -> None:
    rng = np.random.default_rng(6)
    mon = DriftMonitor(DriftSettings(baseline_n=16), residual_baseline_n=24)
    seed = [("P1" if i % 2 else "P2", float(e)) for i, e in enumerate(rng.normal(MU, SIGMA, 28))]
    mon.reset(seed)
    assert mon.residual.charts[OVERALL].mu == np.mean([e for _, e in seed])
    signals = mon.update("P1", MU + 10 * SIGMA, 100)  # the first sample after the apply
    assert {(s.family, s.stream) for s in signals} == {("residual", "P1"), ("residual", OVERALL)}
    fresh = DriftMonitor(DriftSettings(baseline_n=16), residual_baseline_n=24)
    assert [fresh.update("P1", MU + 10 * SIGMA, i) for i in range(23)] == [[]] * 23  # learning


def test_change_charts_learn_their_baseline_again_at_an_apply() -> None:
    """The first differences hold the warm-up's fast drift: at an apply the change charts take
    the last in-control ones instead, and a knock that the first baseline let pass for one
    sample is flagged at its first."""
    rng = np.random.default_rng(7)
    mon = DriftMonitor(DriftSettings(baseline_n=16))
    for i, d in enumerate(np.abs(rng.normal(0.0, 3 * SIGMA, 16))):  # the first hour
        mon.update("P1", MU, i, float(d))
    first = mon.change.charts[OVERALL].mu
    for i, d in enumerate(np.abs(rng.normal(0.0, SIGMA, 24)), start=16):  # later, quieter
        mon.update("P1", MU, i, float(d))
    mon.reset()  # parameters applied: residual charts start again, change charts learn again
    chart = mon.change.charts[OVERALL]
    assert chart.mu == pytest.approx(np.mean(chart.recent)) and chart.mu < 0.6 * first
    assert not mon.residual.charts
    knock = first + 3.0 * SIGMA
    signals = mon.update("P1", MU, 50, knock)  # the knock seen from a configuration again
    assert [s.family for s in signals] == ["change", "change"] and signals[0].onset_ref == 50


def test_prediction_inflation() -> None:
    assert prediction_inflation(72, 30) == np.sqrt(102 / 42)
    assert prediction_inflation(10**6, 30) < 1.0001


def test_restart_keeps_the_residual_baselines() -> None:
    rng = np.random.default_rng(8)
    mon = DriftMonitor(DriftSettings(baseline_n=8))
    for i, e in enumerate(rng.normal(MU, SIGMA, 20)):
        mon.update("P1", float(e), i, abs(float(e) - MU))
    mon.update("P1", 1.0, 20, 1.0)
    assert mon.drifting
    mu = mon.residual.charts[OVERALL].mu
    mon.restart()
    assert not mon.drifting
    assert mon.residual.charts[OVERALL].mu == mu  # kept; the change charts learn again from
    change = mon.change.charts[OVERALL]  # their last in-control samples (not the 1.0 mm one)
    assert len(change.recent) == 8 and 1.0 not in change.recent
    assert change.mu == pytest.approx(np.mean(change.recent))


def _first_signal(mon: DriftMonitor, values: np.ndarray, first_ref: int = 1) -> int | None:
    """The ref of the first sample that raised a signal of the overall residual chart."""
    for i, e in enumerate(values):
        sigs = mon.update("P1", float(e), first_ref + i)
        if any(s.stream == OVERALL and s.family == "residual" for s in sigs):
            return first_ref + i
    return None


def test_an_unseeded_chart_flags_a_step_while_it_learns_its_baseline() -> None:
    """A new cell (no seed): a knock at the 8th sample, long before the baseline's 24 samples,
    is flagged within 3 samples with its change point at the knock (self-starting CUSUM), and
    it is not learned into the baseline. A chart that only learned flagged nothing there."""
    rng = np.random.default_rng(11)
    e = np.linalg.norm(rng.normal(0.0, 0.03, (24, 3)), axis=1)
    e[7:] += 0.25  # the knock at ref 8
    mon = DriftMonitor(DriftSettings(), residual_baseline_n=24)
    flagged = _first_signal(mon, e)
    assert flagged is not None and 8 <= flagged <= 10, flagged
    chart = mon.residual.charts[OVERALL]
    assert chart.drifting and chart.onset_ref == 8
    assert max(chart.baseline) < 0.2  # nothing after the knock in the baseline


def test_the_self_starting_chart_rarely_signals_in_control() -> None:
    """In-control 3-D error norms over a first schedule cycle (24 samples, 5 streams' worth):
    signals in at most 4 % of 400 new cells (measured 1.7 %)."""
    rng = np.random.default_rng(12)
    signals = 0
    for _ in range(400):
        mon = DriftMonitor(DriftSettings(baseline_n=24), residual_baseline_n=24)
        e = np.linalg.norm(rng.normal(0.0, 0.03, (24, 3)), axis=1)
        signals += _first_signal(mon, e) is not None
    assert signals / 400 <= 0.04, signals


def test_the_self_starting_state_survives_a_restart() -> None:
    rng = np.random.default_rng(13)
    mon = DriftMonitor(DriftSettings(), residual_baseline_n=24)
    e = np.linalg.norm(rng.normal(0.0, 0.03, (10, 3)), axis=1)
    _first_signal(mon, e)
    again = DriftMonitor(DriftSettings(), residual_baseline_n=24)
    again.load_json(mon.to_json())
    assert again.to_json() == mon.to_json()
    # a state saved before the self-starting chart (no ss, jumped) still loads
    doc = mon.to_json()
    for chart in doc["residual"].values():
        chart.pop("ss"), chart.pop("jumped")
    again.load_json(doc)
    assert again.residual.charts[OVERALL].ss == 0.0
