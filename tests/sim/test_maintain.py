"""`rvis maintain` on the simulated line, as a plant lives it (issue 41): a commissioned cell,
the service holding it for maintenance after the event, the procedure on the same state
directory (through the command line, in this process), and the service measuring again. Checked
against the simulated cell's truth; seeds and event times not tuned on."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.config import load_cell
from app.config.write import dumps_cell
from app.formats.files import read_json, write_text
from app.formats.params import from_json
from app.line.statedir import MAINTENANCE_REPORT_JSON, StateDir
from app.line.states import AlarmCode
from app.line.store import Store
from app.sim.commissioned import commission_simulated
from app.sim.line_run import SimulatedLineRun
from app.sim.line_setup import continued_epoch
from app.sim.maintenance import MaintenanceRun, _line_after, _version_x
from tests.groups import GIGE_CAMERA

SEED = 17
AT_S = 780.0  # the event in the 14th clamp period


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory: pytest.TempPathFactory) -> StateDir:
    """A cell commissioned once on the simulated line (every step, geometric path)."""
    state = StateDir(tmp_path_factory.mktemp("commissioned") / "state")
    commission_simulated(load_cell(None), state, SEED)
    return state


def _with_event(
    src: StateDir, dst: Path, kind: str, axis: int = 3, frame: bool = False
) -> StateDir:
    shutil.copytree(src.root, dst)
    state = StateDir(dst)
    cfg = load_cell(state.cell)
    simline = dataclasses.replace(
        cfg.simline,
        maintenance_at_s=AT_S,
        maintenance_kind=kind,
        maintenance_axis=axis,
        maintenance_frame=frame,
    )
    service = dataclasses.replace(cfg.service, state_dir=str(dst.resolve()))
    cfg = dataclasses.replace(cfg, simline=simline, service=service)
    write_text(state.cell, dumps_cell(cfg, "test: a maintenance event"))
    return state


def _line(state: StateDir, windows: int) -> Any:
    cfg = load_cell(state.cell)
    with SimulatedLineRun(cfg, state.root, seed=SEED, geometric=True, plan=state.plan) as sim:
        return sim.run_windows(windows)


def _store(state: StateDir) -> Store:
    return Store.read_only(state.db)


@GIGE_CAMERA
@pytest.mark.parametrize(
    ("kind", "axis", "frame"),
    [("axis", 2, False), ("sensor", 3, False), ("fixture", 3, False), ("fixture", 3, True)],
)
def test_a_procedure_hands_the_cell_back_with_its_history(
    commissioned: StateDir, tmp_path: Path, kind: str, axis: int, frame: bool, capsys: Any
) -> None:
    """Each event; the fixture renewed twice: moving the spheres in the part frame (the
    tracker finds them, the chain as it was) and moving the part frame itself against the
    robot's base (issue 51 item 4: the tracker sees no change, the robot sees every sphere
    moved, and the procedure identifies the part frame)."""
    state = _with_event(commissioned, tmp_path / "state", kind, axis, frame)
    before = _line(state, 30)
    assert before.maintenance, "the service did not hold the cell"
    truth_before = [r.rmse_mm for r in before.records if r.t_open_h * 3600.0 < AT_S]
    store = _store(state)
    try:
        measurements_before = store.last_measurement_id()
        assert store.active_alarms(code=AlarmCode.MAINTENANCE)
    finally:
        store.close()
    args = ["maintain", kind, *([str(axis)] if kind == "axis" else [])]
    code = main([*args, "--sim", "--state-dir", str(state.root), "--yes", "--json"])
    out = capsys.readouterr().out
    report = json.loads(out[out.index("{") :])
    assert code == 0, report
    assert report["complete"]
    folder = state.maintenance / sorted(p.name for p in state.maintenance.iterdir())[0]
    assert (folder / MAINTENANCE_REPORT_JSON).is_file()
    steps = {s["name"]: s for s in report["steps"]}
    version = steps["handover"]["results"]["version"]
    # what the report says (issue 51 item 2): the views seen of those asked (was "24 of 8"
    # for a sensor's, its extra views counted against the plan's alone), the standard
    # uncertainties with their units, the workspace RMS before and after in words
    identified = steps["handeye" if kind == "sensor" else "reidentify"]
    (seen,) = [c for c in identified["checks"] if c["name"] == "views seen"]
    k, n = map(int, seen["value"].split(" of "))
    views = identified["results"]["views"]
    assert k <= n == views["asked"], seen
    if kind == "sensor":
        # the gate is on the plan's views; the extra views at the field of view's edges, aimed
        # on the mount before it is identified, are counted apart (gating on all of them
        # failed the procedure on 4 of 4 of the maintenance campaign's seeds: 50942a4)
        per_sphere = load_cell(state.cell).commission.maintenance_views_per_sphere
        assert n == per_sphere * 4 and views["extra_asked"] > 0, views
        assert 0 <= views["extra_seen"] <= views["extra_asked"], views
    if identified["results"]["identified"]:
        units = {key.rsplit("_", 1)[1] for key in identified["results"]["standard_uncertainty"]}
        assert units <= {"mm", "deg"} and "std" not in identified["results"]
    change = report["headline"]["workspace_change"]
    assert change.startswith("workspace RMS ") and " from 8 positions after and " in change
    # the history kept, the new version in force from the maintenance, the alarm cleared, the
    # suspect interval closed at the hand-over, the record complete
    store = _store(state)
    try:
        applied = store.applied()
        assert applied[-1]["version"] == version and applied[-1]["source"] == "maintenance"
        assert [a["version"] for a in applied] == list(range(1, version + 1))
        assert store.last_measurement_id() == measurements_before
        assert not store.active_alarms(code=AlarmCode.MAINTENANCE)
        suspects = store.suspects()
        assert suspects and all(s["t_end"] is not None for s in suspects)
        assert suspects[-1]["end_reason"] == "maintenance"
        (record,) = store.maintenance()
        assert record["status"] == "done" and record["version_after"] == version
    finally:
        store.close()
    # the version's covariance keeps the held parameters' from the version before (the
    # per-point U95 of app.api counts them), the changed group's its own
    from app.formats.params import covariance_of

    before_cov, after_cov = (covariance_of(state.version_file(v)) for v in (version - 1, version))
    if before_cov is not None:
        assert after_cov is not None and set(before_cov[0]) <= set(after_cov[0])
    # what the procedure found, against the truth
    truth = _line_truth(state, kind)
    if kind == "axis":
        found = steps["reidentify"]["results"]["zero_change_deg"]
        assert found == pytest.approx(truth["zero_change_deg"][axis - 1], abs=0.005)
    if kind == "fixture":
        got = steps["reidentify"]["results"]
        moved = truth["frame_moved_mm"]
        assert (got["group"] == "fixture") == frame, got
        if frame:  # the part frame's move, from the spheres' moves (1-2.5 mm) to 0.1 mm
            assert min(moved.values()) - 0.1 < got["translation_mm"] < max(moved.values()) + 0.1
    # the service measures again on the same directory, not held, at the level the version
    # before the event has at the same times in the world without the event (the procedure's
    # simulation runs in virtual time: the world moves on by its motions and sweeps alone, the
    # same on a loaded machine as on an idle one)
    cfg = load_cell(state.cell)
    run = MaintenanceRun(kind, SEED, axis=axis, at_s=AT_S, after_windows=12, frame=frame)
    after, unchanged = _line_after(cfg, state, run, _version_x(cfg, state, version - 1), None)
    assert not after.maintenance and len(after.records) == 12
    assert after.rejected == 0
    median_after = sorted(r.rmse_mm for r in after.records)[6]
    median_unchanged = sorted(unchanged)[6]
    print(f"{kind}: median after {median_after:.4f} mm, unchanged {median_unchanged:.4f} mm")
    assert median_after < 1.5 * median_unchanged, (truth_before[-5:], unchanged, median_after)
    _a_knock_after_the_hand_over_is_found_named_and_corrected(state, median_after)


@GIGE_CAMERA
def test_a_fixture_renewed_with_no_tracker_is_located_by_the_robot(
    commissioned: StateDir, tmp_path: Path, capsys: Any
) -> None:
    """Issue 51 item 4: the fixture renewed with no tracker at hand (`--no-tracker`). The
    spheres are located by the robot with the version in force, each from the plan's views of
    it: where they truly moved within 0.05 mm (what that version's error at those views
    allows); the workspace validation does not run, and says why (never "passed"); the cell is
    handed back and measures at the level the version before has without the event."""
    state = _with_event(commissioned, tmp_path / "state", "fixture")
    assert _line(state, 30).maintenance, "the service did not hold the cell"
    args = ["maintain", "fixture", "--no-tracker", "--sim", "--state-dir", str(state.root)]
    code = main([*args, "--yes", "--json"])
    out = capsys.readouterr().out
    report = json.loads(out[out.index("{") :])
    assert code == 0 and report["complete"], report
    steps = {s["name"]: s for s in report["steps"]}
    located = steps["spheres"]["results"]
    assert located["source"].startswith("located by the robot")
    truth = _line_truth(state, "fixture")["spheres_moved_mm"]
    assert set(located["moved_mm"]) == set(truth)
    for sphere, moved_mm in truth.items():
        assert located["moved_mm"][sphere] == pytest.approx(moved_mm, abs=0.05), sphere
    assert steps["workspace"]["status"] == "not run", steps["workspace"]
    assert "no tracker" in json.dumps(steps["workspace"]["results"])
    version = steps["handover"]["results"]["version"]
    cfg = load_cell(state.cell)
    run = MaintenanceRun("fixture", SEED, at_s=AT_S, after_windows=8, no_tracker=True)
    after, unchanged = _line_after(cfg, state, run, _version_x(cfg, state, version - 1), None)
    assert not after.maintenance and len(after.records) == 8 and after.rejected == 0
    median_after = sorted(r.rmse_mm for r in after.records)[4]
    assert median_after < 1.5 * sorted(unchanged)[4], (median_after, unchanged)


def _a_knock_after_the_hand_over_is_found_named_and_corrected(
    state: StateDir, level_mm: float
) -> None:
    """Issue 50: the sensor mount knocked 0.3 mm in the line's third window after the
    hand-over (the estimator restarted on the maintenance's version, its prior that
    version's covariance): flagged within 3 windows, named, corrected, the cell back within
    1.5x its level after the hand-over and within its limit within 6 windows."""
    epoch, world_s = continued_epoch(state.root)
    cfg = load_cell(state.cell)
    period = cfg.simline.period_s
    simline = dataclasses.replace(
        cfg.simline, knock_at_s=world_s + 2.5 * period, knock_kind="sensor", knock_mm=0.3
    )
    cfg = dataclasses.replace(cfg, simline=simline)
    write_text(state.cell, dumps_cell(cfg, "test: a knock after the hand-over"))
    with SimulatedLineRun(cfg, state.root, seed=SEED, geometric=True, plan=state.plan) as sim:
        run = sim.run_windows(10)
    knock_t = epoch + 2.5 * period
    store = _store(state)
    try:
        (flag,) = [
            a for a in store.alarms() if a["code"] == "drift_step" and a["t_raised"] >= knock_t
        ]
        (interval,) = [s for s in store.suspects() if s["t_start"] >= knock_t - period]
    finally:
        store.close()
    assert flag["t_raised"] - knock_t <= 3 * period, (flag, knock_t)
    assert interval["group_name"] == "sensor" and interval["end_version"] is not None, interval
    knocked = [r for r in run.records if r.t_h * 3600.0 >= 2.5 * period]
    back = [r.rmse_mm for r in knocked[5:]]  # from the 6th window after the knock on
    limit = cfg.service.accuracy_limit_mm or 0.15
    assert back and max(back) <= min(limit, 1.5 * level_mm), [r.rmse_mm for r in knocked]


def _line_truth(state: StateDir, kind: str) -> dict[str, Any]:
    from app.sim.cell import make_cell
    from app.sim.line_setup import maintenance_of
    from fakes.clock import VirtualClock

    cfg = load_cell(state.cell)
    cell = make_cell(cfg, seed=SEED)
    cell.set_timeline(VirtualClock(), maintenance=maintenance_of(cfg))
    return cell.maintenance_truth()


@GIGE_CAMERA
def test_a_procedure_stopped_half_way_continues_where_it_stopped(
    commissioned: StateDir, tmp_path: Path, capsys: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The engineer declines the workspace step: exit 1, the steps before passed and kept;
    run again, it continues there with the same record and folder."""
    state = _with_event(commissioned, tmp_path / "state", "axis", 3)
    assert _line(state, 30).maintenance
    import app.commands.guided as guided

    def decline_workspace(yes: bool, say: Any) -> Any:
        return lambda question: "workspace" not in question

    monkeypatch.setattr(guided, "confirmation", decline_workspace)
    base = ["maintain", "axis", "3", "--sim", "--state-dir", str(state.root)]
    assert main(base) == 1
    monkeypatch.undo()
    capsys.readouterr()
    (folder,) = list(state.maintenance.iterdir())
    journal = read_json(folder / "journal.json")
    assert [s["name"] for s in journal["steps"] if s["status"] == "passed"] == [
        "devices",
        "prepare",
        "zero",
        "reidentify",
    ]
    assert main([*base, "--yes"]) == 0
    assert list(state.maintenance.iterdir()) == [folder]
    store = _store(state)
    try:
        (record,) = store.maintenance()
        assert record["status"] == "done"
    finally:
        store.close()
    _, x = from_json(state.current)
    assert x.shape[0] > 0


def test_maintain_refuses_what_it_cannot_do(tmp_path: Path, capsys: Any) -> None:
    assert main(["maintain", "axis", "--state-dir", str(tmp_path)]) == 2
    assert "axis's number" in capsys.readouterr().err
    assert main(["maintain", "sensor", "2", "--state-dir", str(tmp_path)]) == 2
    assert main(["maintain", "fixture", "--state-dir", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "rvis commission" in err and err.count("\n") == 2  # one line each


def test_a_knock_after_the_hand_over_is_scored_from_its_window() -> None:
    """The row of a knock after a hand-over (bench/maintenance.py --knocks): the step alarm and
    the jump counted from the knock's window, the first window within the limit from it; a
    wrong kind is refused."""
    from app.sim.line_records import WindowRecord
    from app.sim.maintenance import _knock_row, _KnockLog

    with pytest.raises(ValueError, match="knock"):
        MaintenanceRun("axis", 1, knock="J9")
    log = _KnockLog(limit_mm=0.15)
    events = [{"event": "window"}] * 3 + [{"event": "alarm", "code": "drift_step"}]
    events += [{"event": "window"}, {"event": "window"}, {"event": "jump", "group": "J2"}]
    for e in events:
        log(e)
    rms = [0.04, 0.04, 0.04, 0.3, 0.3, 0.2, 0.1, 0.05]
    records = [WindowRecord(k + 1, 0.0, 20.0, e, e, 1) for k, e in enumerate(rms)]
    row = _knock_row(MaintenanceRun("axis", 1, knock="J2", knock_window=4), records, log)
    assert row["knock_flagged_after_windows"] == 1 and row["knock_attribution"] == "J2"
    assert row["knock_within_limit_after_windows"] == 4
    assert _knock_row(MaintenanceRun("axis", 1), records, log) == {}
