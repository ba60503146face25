"""A knock in the warm-up (issue 28, item 2): on the simulated line with its thermal drift, at
0.5 h while the cell still warms, each kind of knock is attributed to what moved, corrected,
and its suspect interval covers every window the knock put above 1.2x of the pre-knock error
(the truth the simulated line knows: the error at the validation positions), with no false step
alarm before the knock, no overrun, and the cell back within 6 windows. The defaults of the
embedded cell (the campaign docs/results/shift-knocks/ measures them over 8 seeds and 4 hours)."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.config import CellConfig
from app.sim.shift import run_shift
from app.sim.shift_result import ShiftSettings

GROUP_OF = {"sensor": "sensor", "fixture": "fixture", "joint": "J2"}


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["sensor", "fixture", "joint"])
def test_a_knock_in_the_warm_up_is_attributed_corrected_and_its_interval_covers_it(
    cfg: CellConfig, tmp_path: Path, kind: str
) -> None:
    assert cfg.simline.warmup_k > 0  # the warm-up is on
    settings = ShiftSettings(hours=1.0, knock_at_h=0.5, knock=kind)
    r = run_shift(cfg, tmp_path / "state", settings, seed=100)
    k, score = r.knock_window, r.suspect_score
    assert k is not None and score is not None and r.pre_knock_rmse_mm is not None
    recs = {x.window: x for x in r.records}
    # the cell warmed before the knock (the drift the attribution must not take for the step,
    # nor the step for drift; the compliant model's thermal term follows the expansion it causes)
    assert recs[k - 1].temp_c > recs[1].temp_c + 2.0
    assert r.attribution == GROUP_OF[kind]
    assert r.flagged_after is not None and r.flagged_after <= 3
    assert not [w for w in r.step_alarm_windows if w < k]  # no false step alarm in the warm-up
    assert r.summary.overruns == 0
    assert r.recovered_after is not None and r.recovered_after <= 6
    # every window of the knock's episode above the plant's limit is covered, each one the
    # cell vouched for is within the U95 it stated (the relative 1.2x of the level before the
    # knock is information, issue 38 item 5: seed 100's fixture knock leaves the cell 1.21x
    # for a window, 0.079 mm under a stated 0.140), and (the truth says which) at most one
    # window more is covered: the close waits for the measurements of a correction in force
    limit = r.accuracy_limit_mm
    episode = [x for x in r.records if k <= x.window <= (score.episode_end or k)]
    assert all(x.suspect for x in episode if x.rmse_mm > limit), score
    assert all(x.u95_mm is not None and x.rmse_mm <= x.u95_mm for x in episode if not x.suspect)
    assert score.episode_bad and score.episode_bad[0] in score.covered
    assert score.extra <= 1 and not score.covered_before_knock, score
    # and the interval closed on the evidence, at a correction trained after the step: back
    # at the level before the step, or vouched for (its U95 within the plant's limit)
    closed = [s for s in r.suspects if s["t_end"] is not None]
    assert closed and closed[-1]["end_reason"] in ("step", "batch", "sequential", "vouched")
    text = closed[-1]["text"]
    assert "held-out RMS" in text
    vouched_mm = r.accuracy_limit_mm
    if closed[-1]["end_reason"] == "vouched":
        statement = text.rsplit("; ", 1)[-1]
        assert statement.startswith("U95 ") and "<= limit" in statement, statement
        vouched_mm = float(statement.split()[1])
        assert vouched_mm <= r.accuracy_limit_mm
    # what the cell vouched for is true: the window after the close within the U95 it stated
    # (the true RMS at the validation positions), every later one within the limit
    end_h = closed[-1]["t_end_s"] / 3600.0
    after_close = [x for x in r.records if x.t_open_h >= end_h]
    assert after_close and after_close[0].rmse_mm <= vouched_mm, (after_close[0], text)
    assert all(x.rmse_mm <= r.accuracy_limit_mm for x in after_close)
