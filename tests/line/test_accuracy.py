"""What the cell states before a version's first measurement: the one estimator's U95 from the
version's prior at the schedule's views (no seed of residuals beside it), and whether the cell
vouches for the limit (the window's statement after measurements: tests/line/test_jumps.py,
tests/calib/test_cellstate.py; its coverage of the true errors: bench/estimator.py)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.config.line import RecalibSettings
from app.line.accuracy import ESTIMATOR, Accuracy
from calib.uncertainty import norm_quantile, sigma_upper_mm
from tests.line.helpers import make_line


def test_no_evidence_is_not_vouched_for() -> None:
    acc = Accuracy(None, 0, ESTIMATOR, 0.15)
    assert not acc.vouched and "unknown" in acc.text()
    assert Accuracy(0.149, 3, ESTIMATOR, 0.15).vouched
    assert not Accuracy(0.151, 3, ESTIMATOR, 0.15).vouched


def _prior_u95(tmp_path: Path, recalib: RecalibSettings) -> tuple[float | None, float]:
    """(the service's statement before any measurement, the same from the prior by hand: its
    covariance through the model at every view of the schedule, the unmodelled term and the
    measurement's noise)."""
    ln = make_line(tmp_path, recalib=recalib)
    try:
        svc = ln.service
        stated = svc.loop.statement_u95_mm()
        st = svc.jumps.state
        assert st is not None and not st.rows
        q, p = svc.schedule.views(svc.spheres)
        c = svc.model.points_sensor(svc.x, q, p)
        H = svc.model.point_jacobian(svc.x, q, c, list(st.active))
        P = st.P[: st.L, : st.L]
        per_view = np.einsum("kil,lm,kim->k", H, P, H) / 3.0
        s = st.settings
        by_hand = norm_quantile() * math.sqrt(
            float(np.mean(per_view)) + st.s_u_mm**2 + s.sigma_mm**2
        )
        return stated, by_hand
    finally:
        ln.close()


def test_a_version_states_its_prior_before_its_first_measurement(tmp_path: Path) -> None:
    """The nominal parameters (no covariance: the prior of `[service] seq_prior_mm` and
    `seq_prior_rad`) state millimetres and cannot vouch; a tighter prior states less."""
    wide = RecalibSettings(estimator="batch")
    stated, by_hand = _prior_u95(tmp_path / "wide", wide)
    assert stated is not None and abs(stated - by_hand) <= 1e-9 * by_hand
    assert stated > 1.0 and not Accuracy(stated, 0, ESTIMATOR, 0.15).vouched
    tight = replace(wide, seq_prior_mm=0.05, seq_prior_rad=1e-4)
    stated_tight, by_hand_tight = _prior_u95(tmp_path / "tight", tight)
    assert stated_tight is not None and abs(stated_tight - by_hand_tight) <= 1e-9 * by_hand_tight
    assert stated_tight < 0.5 * stated


def test_the_statement_s_floor_is_the_upper_bound_of_the_validation_s_sigma(
    tmp_path: Path,
) -> None:
    """A version validated at 20 workspace positions: the filter's unmodelled term starts at
    their mean square per coordinate less the measurement's noise (the best estimate, what the
    jump test weighs innovations by); the statement's at its upper one-sided 95 % bound (the
    commissioning's own), which a cell's 20 positions need: they know the mean square only to
    about +-18 %."""
    errors = list(np.random.default_rng(5).rayleigh(0.03, 20) * 1.2)
    ln = make_line(
        tmp_path, recalib=RecalibSettings(estimator="batch"),
        initial_residuals={"validation_errors_mm": errors},
    )  # fmt: skip
    try:
        svc = ln.service
        st = svc.jumps.state
        assert st is not None and not st.rows
        sigma2 = st.settings.sigma_mm**2
        plain = math.sqrt(float(np.mean(np.square(errors))) / 3.0 - sigma2)
        bound = math.sqrt(sigma_upper_mm(errors) ** 2 - sigma2)
        assert abs(st.s_u_mm - plain) <= 1e-12 and bound > 1.1 * plain
        q, p = svc.schedule.views(svc.spheres)
        c = svc.model.points_sensor(svc.x, q, p)
        H = svc.model.point_jacobian(svc.x, q, c, list(st.active))
        P = st.P[: st.L, : st.L]
        prior = float(np.mean(np.einsum("kil,lm,kim->k", H, P, H))) / 3.0
        by_hand = norm_quantile() * math.sqrt(prior + bound**2 + sigma2)
        stated = svc.loop.statement_u95_mm()
        assert stated is not None and abs(stated - by_hand) <= 1e-9 * by_hand
    finally:
        ln.close()
