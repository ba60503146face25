"""The one estimator on the service (app.line.jumps): a knock of each kind during service is
found, named, corrected and its suspect interval recorded from the last measurement before it
to the correction; in approve mode the correction waits for the engineer, across a restart of
the service; a sphere knocked alone holds the cell for its procedure; a knock after a restart
and after a rollback is found and corrected as in a run that never stopped. The cell knows the
truth (the validation positions)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from app.config.line import RecalibSettings
from fakes.devices import ClampCycle
from fakes.truth import Knock
from tests.line.helpers import (
    ISOTROPIC_NOISE,
    SCALE,
    knock_line,
    line_settings,
    make_line,
    true_rms,
)

GROUP_OF = {"sensor": "sensor", "fixture": "fixture", "joint": "J2", "J3": "J3"}


def _is(kind: str, **fields: Any) -> Any:
    return lambda e: e["event"] == kind and all(e.get(k) == v for k, v in fields.items())


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["sensor", "fixture", "joint", "J3"])
def test_a_knock_is_found_named_corrected_and_its_interval_recorded(
    tmp_path: Path, kind: str
) -> None:
    ln, x_good, val = knock_line(tmp_path, RecalibSettings(estimator="batch"))
    try:
        before = true_rms(ln, val, x_good)
        ln.start()
        ln.windows(3, timeout_s=20.0)
        last_before = ln.service.store.last_measurement_id()
        ln.cell.set_timeline(ln.clock, knock=Knock.of_kind(kind, ln.clock.monotonic()))
        knocked = true_rms(ln, val, x_good)
        opened = ln.wait(_is("suspect_interval", state="open"), 20.0)
        alarm = ln.wait(_is("alarm", code="drift_step"), 5.0)
        n_window = ln.service.decision.counters["windows"]
        named = ln.wait(lambda e: e["event"] == "jump" and e["group"] == GROUP_OF[kind], 30.0)
        applied = ln.wait(_is("parameters_applied"), 20.0)
        windows_to_apply = ln.service.decision.counters["windows"] - n_window
        closed = ln.wait(_is("suspect_interval", state="closed"), 30.0)
        store = ln.service.store
        cal = store.calibration(applied["calibration_id"])
        applied_t = {a["version"]: a["t"] for a in store.applied()}
        row = store.measurements_by_id([last_before])[0]
        status = ln.service.status()
        alarms = [a for a in store.alarms() if a["code"] == "drift_step"]
        after = true_rms(ln, val, ln.service.x)
        ln.stop()
        assert knocked > 2.0 * before, (before, knocked)
        assert alarm["priority"] == "high" and alarm["message"].startswith("step of the cell")
        assert windows_to_apply <= 2
        assert cal is not None and cal["document"]["estimator"]["kind"] == "step"
        assert cal["document"]["estimator"]["group"] == GROUP_OF[kind]
        assert after <= 1.3 * before + 0.01, (before, knocked, after)
        # the interval: from the last measurement before the knock to the correction's apply
        assert closed["id"] == opened["id"] and closed["group"] == GROUP_OF[kind]
        assert closed["last_good_id"] == last_before and closed["t_start"] == row["t"]
        assert closed["end_reason"] == "step" and closed["end_version"] == applied["version"]
        assert closed["t_end"] == applied_t[applied["version"]]
        assert 0.05 < closed["size_mm"] < 3.0
        assert named["text"] in alarms[-1]["message"]  # the alarm names what moved
        assert alarms[-1]["t_cleared"] is not None
        assert status["suspect_intervals"][-1]["state"] == "closed"
        assert status["jump"] is None or status["jump"]["closed"]  # (its group watched)
    finally:
        ln.close()


APPROVE = RecalibSettings(mode="approve", estimator="batch")


def _proposed(ln: Any) -> dict[str, Any]:
    """Three windows, then a sensor knock: the `calibration` event of its correction, pending
    the engineer's approve."""
    ln.start()
    ln.windows(3, timeout_s=20.0)
    ln.cell.set_timeline(ln.clock, knock=Knock.of_kind("sensor", ln.clock.monotonic()))
    return ln.wait(_is("calibration", status="pending"), 40.0)


@pytest.mark.slow
def test_in_approve_mode_the_correction_waits_for_the_engineer(tmp_path: Path) -> None:
    ln, x_good, val = knock_line(tmp_path, APPROVE)
    try:
        pending = _proposed(ln)
        ln.windows(1, timeout_s=20.0)
        status = ln.service.status()
        assert status["jump"] is not None and status["jump"]["group"] == "sensor"
        assert status["suspect_intervals"][-1]["state"] == "open"
        assert status["pending_calibration"] == pending["id"]
        reply = ln.service.request("approve", {"calibration": pending["id"]}).result(10.0)
        assert reply["ok"], reply
        closed = ln.wait(_is("suspect_interval", state="closed"), 40.0)
        after = true_rms(ln, val, ln.service.x)
        before = true_rms(ln, val, x_good)
        ln.stop()
        assert closed["end_version"] == reply["version"] and closed["end_reason"] == "step"
        assert after <= 1.3 * before + 0.01, (before, after)
    finally:
        ln.close()


@pytest.mark.slow
def test_a_sphere_knocked_alone_holds_the_cell_for_its_procedure(tmp_path: Path) -> None:
    ln, _, _ = knock_line(tmp_path, RecalibSettings(estimator="batch"))
    try:
        ln.start()
        ln.windows(3, timeout_s=20.0)
        ln.cell.set_timeline(ln.clock, knock=Knock.of_kind("sphere", ln.clock.monotonic()))
        held = ln.wait(_is("alarm", code="maintenance"), 40.0)
        store = ln.service.store
        interval = store.suspects()[-1]
        moved = ln.cell._sphere_knocked
        corrections = [c for c in store.calibrations() if (c["document"] or {}).get("estimator")]
        needed = ln.service.status()["maintenance"]["needed"]
        ln.stop()
        assert moved is not None
        assert f"sphere {moved[0]} moved" in held["message"]
        # what moved and the procedure as fields (the alarm's detail), not parsed from its text
        assert held["detail"]["group"] == moved[0] and needed["group"] == moved[0]
        assert needed["procedures"] == ["rvis maintain fixture"] == held["detail"]["procedures"]
        assert needed["what"].startswith(f"sphere {moved[0]} moved") and needed["moved_mm"] > 0
        assert interval["group_name"] == f"sphere:{moved[0]}" and interval["t_end"] is None
        assert not corrections  # no parameter moved for a sphere that did
    finally:
        ln.close()


@pytest.mark.slow
def test_an_episode_waiting_for_its_approve_survives_a_restart(tmp_path: Path) -> None:
    """The correction proposed (approve mode), the service stopped and started again on the
    same state directory (the cell still knocked): the same jump in hand, its interval open,
    its correction still pending; approved, the interval closes at it."""
    ln, _, _ = knock_line(tmp_path, APPROVE)
    try:
        pending = _proposed(ln)
        before = ln.service.status()
    finally:
        ln.close()
    assert before["jump"] is not None and before["jump"]["group"] == "sensor"
    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    again = make_line(
        tmp_path / "state",
        cycle=cycle,
        line=line_settings(window_s=32.0, slots_per_window=8),
        recalib=APPROVE,
        **ISOTROPIC_NOISE,
    )
    try:  # the same cell, knocked from its start (the knock's direction is the cell's seed's)
        again.cell.set_timeline(again.clock, knock=Knock.of_kind("sensor", 0.0))
        assert again.service.status()["jump"] == before["jump"]  # from the database, at once
        again.start()
        again.wait(_is("started"), 20.0)
        status = again.service.status()
        assert status["suspect_intervals"][-1]["state"] == "open"
        assert status["pending_calibration"] == pending["id"]
        reply = again.service.request("approve", {"calibration": pending["id"]}).result(10.0)
        assert reply["ok"], reply
        closed = again.wait(_is("suspect_interval", state="closed"), 40.0)
        assert closed["id"] == before["suspect_intervals"][-1]["id"]
        assert closed["end_version"] == reply["version"]
    finally:
        again.close()


def _restarted(tmp_path: Path, recalib: RecalibSettings) -> Any:
    """The knock line's state directory served again by a new service (a restart)."""
    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    return make_line(
        tmp_path / "state",
        cycle=cycle,
        line=line_settings(window_s=32.0, slots_per_window=8),
        recalib=recalib,
        **ISOTROPIC_NOISE,
    )


def _found_and_corrected(ln: Any, val: Any, x_good: Any, kind: str) -> None:
    """A knock of `kind` now: flagged within a window, named, corrected within two more, its
    interval closed at the correction, the cell back near its level before."""
    before = true_rms(ln, val, x_good)
    ln.cell.set_timeline(ln.clock, knock=Knock.of_kind(kind, ln.clock.monotonic()))
    n = ln.service.decision.counters["windows"]
    ln.wait(_is("alarm", code="drift_step"), 20.0)
    flagged = ln.service.decision.counters["windows"] - n
    ln.wait(lambda e: e["event"] == "jump" and e["group"] == GROUP_OF[kind], 30.0)
    applied = ln.wait(_is("parameters_applied"), 20.0)
    corrected = ln.service.decision.counters["windows"] - n
    closed = ln.wait(_is("suspect_interval", state="closed"), 30.0)
    after = true_rms(ln, val, ln.service.x)
    assert flagged <= 1 and corrected <= 3, (flagged, corrected)
    assert closed["group"] == GROUP_OF[kind] and closed["end_version"] == applied["version"]
    assert after <= 1.3 * before + 0.01, (before, after)


@pytest.mark.slow
def test_a_knock_after_a_restart_is_found_and_corrected(tmp_path: Path) -> None:
    """The service stopped and started again on its state directory (the estimator replays
    the version's measurements), then a fixture knock: found, named, corrected as in a run
    that never stopped."""
    recalib = RecalibSettings(estimator="batch")
    ln, x_good, val = knock_line(tmp_path, recalib)
    try:
        ln.start()
        ln.windows(3, timeout_s=20.0)
    finally:
        ln.close()
    again = _restarted(tmp_path, recalib)
    try:
        again.start()
        again.windows(1, timeout_s=20.0)
        _found_and_corrected(again, val, x_good, "fixture")
    finally:
        again.close()


@pytest.mark.slow
def test_a_knock_after_a_rollback_is_found_and_corrected(tmp_path: Path) -> None:
    """An in-line version, the engineer's rollback to the commissioning's (auto mode holds
    the automatic applies) and resume (the hold lifted), then a sensor knock: the estimator
    restarted on the rolled-back version finds, names and corrects it."""
    ln, x_good, val = knock_line(tmp_path, RecalibSettings(estimator="batch", every_n=16))
    try:
        ln.start()
        ln.wait(_is("parameters_applied"), 60.0)  # the first in-line recalibration
        rolled = ln.service.request("rollback", {"version": 1}).result(20.0)
        assert rolled["ok"] and rolled["held"], rolled
        resumed = ln.service.request("resume").result(20.0)
        pending = ln.service.decision.pending_calibration
        if resumed["held"] and pending is not None:  # a calibration landed meanwhile: refused
            assert ln.service.request("reject", {"calibration": pending}).result(20.0)["ok"]
            resumed = ln.service.request("resume").result(20.0)
        assert resumed["ok"] and not resumed["held"], resumed
        ln.windows(1, timeout_s=20.0)
        assert ln.service.version == 1 and ln.service.decision.auto_hold is None
        _found_and_corrected(ln, val, x_good, "sensor")
    finally:
        ln.close()
