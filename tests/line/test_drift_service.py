"""A knock on the sensor mount during service: the drift charts flag it within a few
measurements, the next recalibration uses only measurements after it, and the accuracy at
validation positions (the cell knows the truth) comes back to its pre-knock level."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from app.config.line import RecalibSettings
from fakes.truth import Knock
from tests.line.helpers import knock_line, true_rms


@pytest.mark.slow
@pytest.mark.parametrize("pre_windows", [3, 6])
def test_a_knock_is_flagged_and_the_recalibration_restores_the_accuracy(
    tmp_path: Path, pre_windows: int
) -> None:
    """3 windows (24 measurements) before the knock: only the residual charts watch (their
    baseline is one schedule cycle); 6 windows: the change charts watch too (a second visit of
    every configuration and 16 differences) and the step is theirs."""
    ln, x_good, val = knock_line(tmp_path, RecalibSettings(estimator="batch", detector="charts"))
    try:
        before = true_rms(ln, val, x_good)
        ln.start()
        for _ in range(pre_windows):
            ln.wait(lambda e: e["event"] == "window")
        assert ln.service.drift.change_watching == (pre_windows == 6)
        n_before = ln.service.store.counts()["ok"]
        # the knock, now: the sensor mount moves by 0.3 mm and tilts by 0.05 deg
        ln.cell.set_timeline(ln.clock, knock=Knock(at_s=ln.clock.monotonic()))
        knocked = true_rms(ln, val, x_good)
        alarm = ln.wait(lambda e: e["event"] == "alarm" and e["code"] == "drift_step", 20.0)
        if pre_windows == 6:
            assert (
                "change since the last visit" in alarm["message"] or "residual" in alarm["message"]
            )
        flagged_at = ln.service.drift_onset_id
        applied = ln.wait(lambda e: e["event"] == "parameters_applied", 60.0)
        cal = ln.service.store.calibrations("applied")[-1]
        ln.stop()
        assert flagged_at is not None and flagged_at - n_before <= 3, (flagged_at, n_before)
        assert "step of" in alarm["message"] and alarm["priority"] == "high"
        # the onset is set by a change chart once they watch (a residual signal then only
        # brings the recalibration forward): either way the set starts after the knock
        assert cal["first_id"] >= flagged_at  # only measurements after the knock
        after = true_rms(ln, val, ln.service.x)
        assert knocked > 3 * before
        assert after <= 1.2 * before + 0.01, (before, knocked, after)
        assert applied["version"] == 2
    finally:
        ln.close()


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["cycle", "adaptive"])
def test_the_sequential_estimator_follows_a_knock(tmp_path: Path, schedule: str) -> None:
    """[service] estimator = "sequential": the drift charts flag the knock, the estimator's
    covariance is widened (the attributed group's) before the post-knock measurements reach it
    (they wait until the step is attributed), and the parameters it proposes, gated and
    applied, bring the true accuracy back."""
    recalib = RecalibSettings(estimator="sequential", schedule=schedule, detector="charts")
    ln, x_good, val = knock_line(tmp_path, recalib)
    try:
        before = true_rms(ln, val, x_good)
        ln.start()
        ln.windows(6, timeout_s=20.0)
        assert ln.service.sequential is not None and ln.service.drift.change_watching
        ln.cell.set_timeline(ln.clock, knock=Knock(at_s=ln.clock.monotonic()))
        knocked = true_rms(ln, val, x_good)
        # the high alarm once the attribution confirms the step (a low one before)
        alarm = ln.wait(lambda e: e["event"] == "alarm" and e["code"] == "drift_step", 20.0)
        assert "change since" in alarm["message"] and " | sensor mount moved" in alarm["message"]
        assert ln.service.store.active_alarms(code="drift_step")
        # the covariance is widened once the step is attributed (the sensor group's only)
        ln.wait(  # decisive (BIC margin >= step_min_margin): the group is widened then
            lambda e: (
                e["event"] == "step_attribution"
                and e["choice"] not in ("none", "several")
                and (e["attribution"]["margin"] or 1e9) >= 10.0
            ),
            20.0,
        )
        assert ln.service.sequential.est is not None and ln.service.sequential.est.n_knocks >= 1
        ln.wait(
            lambda e: e["event"] == "parameters_applied" and ln.service.drift_onset_id is None,
            90.0,
        )
        first = true_rms(ln, val, ln.service.x)
        # the filter goes on refining: measured, the first candidate after a step is within
        # 1.5x of the pre-knock error, the next ones within 1.2x (docs: app/line/inline_seq.py)
        ln.wait(lambda e: e["event"] == "parameters_applied", 60.0)
        after = true_rms(ln, val, ln.service.x)
        cal = ln.service.store.calibrations("applied")[-1]
        slots = [r["slot"] for r in ln.service.store.measurements()]
        ln.stop()
        assert cal["document"]["estimator"]["kind"] == "sequential"
        in_turn = np.mean([b == (a + 1) % 24 for a, b in itertools.pairwise(slots)])
        # cycled: in turn but for a slot that did not fit a window's rest and the windows that
        # measured for the step (until the recovery test showed the cell back); adaptive: by
        # information, mostly not the next one
        assert in_turn > 0.7 if schedule == "cycle" else in_turn < 0.5, in_turn
        assert knocked > 3 * before
        assert first <= 1.5 * before + 0.01 and after <= 1.2 * before + 0.01, (
            before,
            knocked,
            first,
            after,
        )
    finally:
        ln.close()
