"""U95 from a check standard's residual norms: its coverage of a new point's error is about
95 % however few norms it has (the upper bound pays for them), and it is not inflated with
many (about 1.62x the RMS of the error norm, REFERENCE.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.uncertainty import chi2_ppf, norm_quantile, sigma_upper_mm, u95_mm


def test_the_norm_quantile_of_a_3d_error_is_2_80_sigma() -> None:
    assert norm_quantile() == pytest.approx(2.7955, abs=1e-4)


def test_the_chi_square_quantile_is_scipy_stats_own_to_the_bit() -> None:
    """chi2_ppf (scipy.special alone, so that no process imports scipy.stats to state an
    uncertainty) returns what scipy.stats.chi2.ppf does, bit for bit: every decision on it
    (the gates, the jump test's "explains", the bounds) unchanged."""
    from scipy.stats import chi2

    for p in (1e-5, 0.05, 0.5, 0.95, 0.99, 0.999):
        for dof in (1, 2, 3, 6, 7, 60, 300, 3000):
            assert chi2_ppf(p, dof) == float(chi2.ppf(p, dof)), (p, dof)


def test_no_evidence_states_nothing() -> None:
    assert math.isnan(u95_mm([])) and math.isnan(sigma_upper_mm([]))


@pytest.mark.parametrize("n", [1, 3, 24])
def test_u95_covers_a_new_point_at_least_95_percent(n: int) -> None:
    """Monte Carlo: n evidence norms and a new point's norm from the same 3-D normal error;
    the new norm is within U95 in >= 95 % of draws (the upper bound makes it more with few)."""
    rng = np.random.default_rng(n)
    sigma, draws = 0.03, 4000
    ev = np.linalg.norm(rng.normal(0.0, sigma, (draws, n, 3)), axis=2)
    new = np.linalg.norm(rng.normal(0.0, sigma, (draws, 3)), axis=1)
    u = np.array([u95_mm(list(e)) for e in ev])
    covered = float(np.mean(new <= u))
    assert 0.95 <= covered <= 0.995, covered


def test_u95_with_much_evidence_is_1_6x_the_rms_of_the_error_norm() -> None:
    rng = np.random.default_rng(7)
    e = np.linalg.norm(rng.normal(0.0, 0.03, (5000, 3)), axis=1)
    rms = float(np.sqrt(np.mean(e**2)))
    assert u95_mm(list(e)) / rms == pytest.approx(1.62, abs=0.03)


def test_a_term_the_evidence_lacks_adds_in_quadrature() -> None:
    e = [0.03, 0.05, 0.04, 0.02]
    s = sigma_upper_mm(e)
    assert u95_mm(e, 0.02) == pytest.approx(norm_quantile() * math.hypot(s, 0.02))


def test_a_candidate_is_shown_worse_only_when_the_held_out_points_show_it() -> None:
    """Four held-out points: a candidate a few micrometres worse on each is not shown worse
    when the points disagree, and is when every point is clearly worse; never by RMS alone."""
    from calib.uncertainty import shown_worse

    current = [0.030, 0.045, 0.020, 0.050]
    assert not shown_worse([0.035, 0.040, 0.026, 0.052], current)  # RMS worse, not shown
    assert shown_worse([0.060, 0.075, 0.050, 0.080], current)
    assert not shown_worse([0.010, 0.020, 0.015, 0.030], current)  # better
    # the false "worse" rate on candidates as good as the current: about 5 %
    rng = np.random.default_rng(3)
    e = np.linalg.norm(rng.normal(0.0, 0.03, (4000, 2, 4, 3)), axis=3)
    rate = float(np.mean([shown_worse(list(a), list(b)) for a, b in e]))
    assert 0.02 <= rate <= 0.08, rate
