"""A new cell knows its accuracy from its first window: a knock in the first schedule cycle (one
slot per window, as a cell's default) is found by the one estimator within 3 windows and named
to what moved (the commissioning's covariance is the prior: no "new cell" case), the windows
whose true error is above the plant's limit (the default: VDA 5's or 1.5x the cell's own
commissioned U95) are suspect, and the cell is back within the limit
and vouching by the end. Seeds and knock times named before these tests ran under the one
estimator (they were the drift charts' cases: the estimator was not tuned on them)."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.config import CellConfig
from app.sim.shift import run_shift
from app.sim.shift_result import ShiftSettings

pytestmark = pytest.mark.slow

GROUP = {"sensor": "sensor", "fixture": "fixture", "joint": "J2"}


@pytest.mark.parametrize(
    ("kind", "seed", "at_h"), [("fixture", 2, 0.2), ("joint", 7, 0.12), ("sensor", 14, 0.1)]
)
def test_a_knock_in_a_new_cells_first_cycle(
    cfg: CellConfig, tmp_path: Path, kind: str, seed: int, at_h: float
) -> None:
    settings = ShiftSettings(hours=0.6, knock_at_h=at_h, knock=kind)
    result = run_shift(cfg, tmp_path / "state", settings, seed=seed)
    recs, k = result.records, result.knock_window
    assert k is not None and k < 24  # in the first schedule cycle
    assert result.flagged_after is not None and result.flagged_after <= 3
    assert result.attribution == GROUP[kind]
    assert not [w for w in result.drift_alarm_windows if w < k]  # nothing before the knock
    limit = result.accuracy_limit_mm
    bad = [r for r in recs if r.rmse_mm > 1.2 * limit]
    assert all(r.suspect for r in bad), [(r.window, r.rmse_mm) for r in bad]
    # back within the limit after the correction, vouched for again
    assert not recs[-1].suspect and recs[-1].rmse_mm <= limit, recs[-1]
