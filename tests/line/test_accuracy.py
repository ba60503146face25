"""What the service counts as evidence for its U95: the measurements taken with the version in
force (held out), topped up by the version's seed without a step, only those from a flagged
step's change point on with one; and whether the cell vouches for the limit."""

from __future__ import annotations

import numpy as np
import pytest

from app.line.accuracy import (
    PREDICTED,
    document_seed,
    evidence,
    seed_count,
    statement,
    with_prediction,
)
from calib.uncertainty import norm_quantile, shown_larger


def _rows(residuals: list[float], version: int, first_id: int = 1) -> list[dict[str, object]]:
    return [
        {"id": first_id + k, "residual_mm": e, "params_version": version}
        for k, e in enumerate(residuals)
    ]


def test_held_out_measurements_of_the_version_in_force_topped_up_by_its_seed() -> None:
    rows = _rows([0.5, 0.5], 1) + _rows([0.03, 0.04], 2, first_id=3)
    norms, basis = evidence(rows, 2, None, [0.02] * 4, n_max=5)
    assert norms == [0.02, 0.02, 0.02, 0.03, 0.04] and basis == "held-out+seed"
    norms, basis = evidence(rows, 2, None, [], n_max=5)
    assert norms == [0.03, 0.04] and basis == "held-out"


def test_a_validation_longer_than_a_cycle_counts_whole_then_in_proportion() -> None:
    """A seed of at most a cycle tops the held-out norms up to a cycle (as before); a longer
    one (a workspace validation at 50 positions) counts whole beside the first held-out norm
    and is displaced in proportion as the held-out norms fill the cycle."""
    assert [seed_count(20, h, 24) for h in (0, 1, 5, 23)] == [24, 23, 19, 1]
    assert [seed_count(50, h, 24) for h in (0, 1, 12, 23)] == [50, 48, 25, 3]
    seed = [0.06] * 30 + [0.05] * 20
    norms, basis = evidence(_rows([0.04], 1), 1, None, seed, n_max=24)
    assert norms == [*seed[-48:], 0.04] and basis == "held-out+seed"
    norms, _ = evidence(_rows([0.04] * 24, 1), 1, None, seed, n_max=24)
    assert norms == [0.04] * 24


def test_a_flagged_step_counts_only_the_measurements_after_it() -> None:
    rows = _rows([0.03, 0.04, 0.9, 1.1], 1)
    norms, basis = evidence(rows, 1, 3, [0.02] * 10, n_max=24)
    assert norms == [0.9, 1.1] and basis == "after step"
    acc = statement(norms, basis, 0.15)
    assert acc.u95_mm is not None and acc.u95_mm > 1.0 and not acc.vouched


def test_no_evidence_is_not_vouched_for() -> None:
    norms, basis = evidence([], 1, None, [], n_max=24)
    acc = statement(norms, basis, 0.15)
    assert (acc.u95_mm, acc.basis, acc.vouched) == (None, "none", False)
    assert "unknown" in acc.text()


def test_a_cycle_of_good_evidence_is_vouched_for() -> None:
    acc = statement([0.03] * 24, "held-out", 0.15)
    # norms of 0.03 mm: sigma 0.017 mm per coordinate, U95 about 1.6 x 0.03 plus the bound
    assert acc.u95_mm is not None and 0.048 < acc.u95_mm < 0.07 and acc.vouched


def test_a_commissioned_version_is_seeded_by_its_workspace_validation() -> None:
    """A version no calibration here made states from its commissioning's workspace validation
    when its document carries it (prediction errors where the line measures: the simulated
    line's commissioning parameters are 0.098 mm off at the validation points while their
    training residuals, scaled, say 0.055), else from its training residuals scaled."""
    residuals = {"n_measurements": 24, "rms_mm": 0.035, "n_parameters": 30}
    doc: dict[str, object] = {"residuals": residuals, "n_parameters": 30}
    scaled = document_seed(doc)
    assert len(scaled) == 24 and scaled[0] == pytest.approx(0.035 * np.sqrt(102 / 42))
    errors = [0.05, 0.12, 0.08, 0.2]
    assert document_seed({**doc, "validation": {"errors_mm": errors}}) == errors
    assert document_seed({**doc, "validation": {"errors_mm": []}}) == scaled
    assert document_seed(None) == []


def test_a_fast_correction_states_its_predicted_uncertainty_until_contradicted() -> None:
    """After a fast correction the cell states the correction's predicted sigma (the level
    before the step and the correction's own, in quadrature) while the few residuals after it
    do not show it larger and do not bound it lower themselves; a cycle of them, a
    contradiction or no prediction: the residuals' own bound."""
    sigma = 0.045  # per coordinate: U95 0.126 mm
    few = statement([0.07] * 6, "after step", 0.15)  # 6 norms: their bound alone 0.18 mm
    assert few.u95_mm is not None and few.u95_mm > 0.15
    acc = with_prediction(few, [0.07] * 6, sigma, n_max=24)
    assert acc.basis == PREDICTED and acc.u95_mm == pytest.approx(norm_quantile() * sigma)
    assert acc.vouched and acc.n == 6
    # residuals that show the sigma larger: the prediction does not stand
    big = statement([0.15] * 6, "after step", 0.15)
    assert shown_larger([0.15] * 6, sigma) and with_prediction(big, [0.15] * 6, sigma, 24) == big
    # a cycle of residuals, none, no prediction, or not after a step: as stated
    full = statement([0.07] * 24, "after step", 0.15)
    assert with_prediction(full, [0.07] * 24, sigma, 24) == full
    none = statement([], "none", 0.15)
    assert with_prediction(none, [], sigma, 24) == none
    assert with_prediction(few, [0.07] * 6, None, 24) == few
    seeded = statement([0.07] * 6, "held-out+seed", 0.15)
    assert with_prediction(seeded, [0.07] * 6, sigma, 24) == seeded
    # residuals that bound it lower themselves: theirs
    small = statement([0.01] * 12, "after step", 0.15)
    assert with_prediction(small, [0.01] * 12, sigma, 24) == small
