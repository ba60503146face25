"""A version's U95 seed (its commissioning's workspace validation, else its training residuals
scaled to prediction errors), the statement of a set of residual norms, and whether the cell
vouches for the limit (the window's statement is the one estimator's: tests/line/test_jumps.py,
tests/calib/test_cellstate.py)."""

from __future__ import annotations

import numpy as np
import pytest

from app.line.accuracy import document_seed, statement


def _rows(residuals: list[float], version: int, first_id: int = 1) -> list[dict[str, object]]:
    return [
        {"id": first_id + k, "residual_mm": e, "params_version": version}
        for k, e in enumerate(residuals)
    ]


def test_no_evidence_is_not_vouched_for() -> None:
    acc = statement([], "none", 0.15)
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
