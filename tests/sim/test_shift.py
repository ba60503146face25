"""The compressed shift (app/sim/shift.py) on a short run: a knock of the sensor mount moves the
truth, a recalibration is applied after the knock, and the true
error with the service ends back near its pre-knock level and well below the error of the
commissioning parameters (the truth the simulated line knows). Warm-up off here so that the
knock is the only drift of the truth."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import build_parser, main
from app.commands.experiment_shift import hours_list, knock_hours
from app.config import CellConfig
from app.line.store import Store
from app.sim.knocks import load_campaign, run_row
from app.sim.shift import run_shift
from app.sim.shift_report import summary_lines, write_outputs
from app.sim.shift_result import ShiftSettings
from app.sim.shift_score import SuspectScore, episode_end


def test_a_knock_is_flagged_and_the_service_recovers(cfg: CellConfig, tmp_path: Path) -> None:
    cold = dataclasses.replace(cfg, simline=dataclasses.replace(cfg.simline, warmup_k=0.0))
    settings = ShiftSettings(hours=0.8, knock_at_h=0.25, slots_per_window=2)
    result = run_shift(cold, tmp_path / "state", settings, seed=3)
    recs, k = result.records, result.knock_window
    assert result.summary.windows == 48 and k is not None
    # the knock really moved the truth: the commissioning parameters got worse at once (the
    # window before the knock's is recorded a moment before it: under load, after it)
    before, after = recs[k - 3], recs[k]
    assert after.rmse_commissioning_mm > before.rmse_commissioning_mm + 0.1
    # flagged at once: the change charts watch from the second visit of every configuration
    assert result.flagged_after is not None and result.flagged_after <= 3
    # a recalibration was applied after the knock and the error with the service is back down
    assert any(w > k for w in result.applied_windows)
    final = recs[-1]
    assert final.version > recs[k - 1].version
    assert final.rmse_mm < 0.5 * final.rmse_commissioning_mm
    # the outputs hold the same figures
    md, js, png = write_outputs(result, tmp_path / "out", "rvis experiment shift (test)")
    doc = json.loads(js.read_text())
    assert doc["flagged_after_windows"] == result.flagged_after
    assert len(doc["summary"]["timeline"]) == 48
    assert png.stat().st_size > 10_000 and "| 0-1 |" in md.read_text()
    lines = summary_lines(result)
    assert any("flagged by the step alarm after" in line for line in lines)
    # issue 50's measure: the windows until the true RMS is within the limit, as the records say
    limit = result.accuracy_limit_mm
    back = next(r.window for r in recs if r.window >= k and r.rmse_mm <= limit) - k + 1
    assert result.within_limit_after == back and doc["within_limit_after_windows"] == back
    assert any(f"within the limit ({limit:g} mm) after {back} window" in line for line in lines)


def _shift_doc(
    cfg: CellConfig, state: Path, busy: bool, estimator: str
) -> tuple[dict[str, Any], list[Any]]:
    """A short shift (a knock, a recalibration): its shift.json document less the wall time,
    and its stored measurements. busy: with a thread beside it that computes all along (the
    interpreter's threads then interleave differently: what must not change anything)."""
    settings = ShiftSettings(hours=0.3, knock_at_h=0.15, slots_per_window=2, estimator=estimator)
    done = threading.Event()

    def spin() -> None:
        while not done.is_set():
            sum(i * i for i in range(2_000))
            time.sleep(0)  # sleep-ok: yields the interpreter, a load generator's step

    hog = threading.Thread(target=spin, daemon=True)
    if busy:
        hog.start()
    try:
        result = run_shift(cfg, state, settings, seed=3)
    finally:
        done.set()
    doc = result.to_json()
    assert doc.pop("real_s") > 0
    rows = Store(state / "rvis.db").measurements()
    return json.loads(json.dumps(doc)), rows


@pytest.mark.parametrize("estimator", ["batch", "sequential"])
def test_one_seed_one_shift_whatever_the_load(
    cfg: CellConfig, tmp_path: Path, estimator: str
) -> None:
    """The line runs in virtual time: two runs of a seed are the same shift, field by field
    and measurement by measurement, also with the interpreter busy beside the second."""
    first, rows_1 = _shift_doc(cfg, tmp_path / "a", busy=False, estimator=estimator)
    second, rows_2 = _shift_doc(cfg, tmp_path / "b", busy=True, estimator=estimator)
    sm = first["summary"]
    assert sm["windows"] == 18 and sm["measurements"] >= 30 and sm["overruns"] == 0
    if estimator == "batch":  # a worker's outcome, seen at its modelled time
        assert sm["calibrations_applied"] >= 1
    for key in first:
        assert second[key] == first[key], key
    assert len(rows_1) == len(rows_2)
    for a, b in zip(rows_1, rows_2, strict=True):
        assert a == b


def test_shift_settings_refuse_a_knock_outside_the_shift() -> None:
    with pytest.raises(ValueError, match="knock_at_h"):
        ShiftSettings(hours=2.0, knock_at_h=2.0)


@pytest.mark.parametrize(
    "argv",
    [
        ["--knock-at-h", "9"],
        ["--hours", "0"],
        ["--scale", "-1"],
        ["--geometric", "--rendered"],
        ["--knock", "none", "--seeds", "2"],
        ["--knock", "none", "--knock-at-window", "3"],
        ["--knock-at-window", "3", "--before-knock", "restart"],
        ["--knock", "none", "--hours", "1", "--before-knock", "rollback"],
        ["--seeds", "2", "--knock-at-window", "8", "--before-knock", "restart"],
    ],
)
def test_bad_shift_options_exit_2(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["experiment", "shift", "--out", str(tmp_path / "x"), *argv])
    assert code == 2 and "rvis" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_a_shift_without_a_knock_keeps_the_shifts_fields(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--knock none` (issue 50 item 6): the knock's fields empty, the windows' as with one."""
    out = tmp_path / "quiet"
    assert (
        main(["experiment", "shift", "--knock", "none", "--hours", "0.1", "--out", str(out)]) == 0
    )
    assert "no knock" in capsys.readouterr().out
    doc = json.loads((out / "shift.json").read_text())
    assert doc["knock_window"] is None and doc["flagged_after_windows"] is None
    assert doc["attribution"] is None and doc["step_alarm_windows"] == []
    assert doc["settings"]["knock"] == "none" and doc["accuracy_limit_mm"] > 0
    timeline = doc["summary"]["timeline"]
    assert len(timeline) == 6 and not any(w["suspect"] for w in timeline)
    assert {"rmse_mm", "p95_mm", "u95_mm", "within_u95", "suspect"} <= set(timeline[0])


def test_the_estimator_comparison_runs_each_way_on_the_same_cell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cmp"
    argv = ["experiment", "shift", "--hours", "0.15", "--knock-at-h", "0.1"]
    assert (
        main([*argv, "--slots-per-window", "2", "--estimator", "compare", "--out", str(out)]) == 0
    )
    rows = json.loads((out / "shift-estimators.json").read_text())["rows"]
    assert [r["name"] for r in rows] == [
        "no recalibration",
        "batch",
        "sequential",
        "sequential, adaptive",
    ]
    for sub in ("batch", "sequential", "sequential-adaptive"):  # one shift each, its own state
        assert (out / sub / "shift.json").exists() and (out / sub / "state" / "rvis.db").exists()
    md = (out / "shift-estimators.md").read_text()
    assert "| sequential, adaptive |" in md and (out / "shift-estimators.png").stat().st_size > 5000
    assert all(r["mean_mm"] > 0 for r in rows)


@pytest.mark.slow
def test_a_knock_is_attributed_and_scored_in_a_campaign(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--knock sensor --seeds 1` through the command line: a short shift (the change charts
    watch from about window 20 at 2 slots per window), the campaign table with the must-show
    columns, and the suspect intervals scored against the truth. The sensor knock, the slowest
    to correct (6 parameters, rotations among them); every kind is attributed, corrected and
    recorded in the service by tests/line/test_step.py, and the campaign over 10 seeds of each
    is docs/results/shift-knocks. No warm-up here: the windows above 1.2x of the pre-knock level
    are the knock's alone (the warm-up's drift after a correction would count too, and is
    steepest in the first hour)."""
    out, cell = tmp_path / "knocks", tmp_path / "cell.toml"
    cell.write_text("[simline]\nwarmup_k = 0.0\n")
    argv = ["experiment", "shift", "--hours", "0.7", "--knock-at-h", "0.45"]
    argv += ["--slots-per-window", "2", "--knock", "sensor", "--seeds", "1", "--out", str(out)]
    argv += ["--cell", str(cell)]
    assert main(argv) == 0
    doc = json.loads((out / "shift-knocks.json").read_text())
    (r,) = doc["rows"]
    assert r["knock"] == "sensor" and r["attribution"] == ["sensor"], r
    # the mechanism, not the target (the campaign in docs/results/shift-knocks measures that):
    # a rolling set of 24 at 2 slots per window would take 12 windows; a correction of the
    # attributed group takes a fraction of that
    assert r["recovered_after"][0] is not None and r["recovered_after"][0] <= 8, r
    assert r["false_step_alarms_before_knock"] == 0 and r["overruns"] == 0
    run = doc["runs"]["sensor"][0]
    assert run["suspects"] and run["suspects"][-1]["t_end_s"] is not None
    assert _covered_until_the_correction(run), run["suspects"]
    # the windows the knock left above 1.2x the level before it (and above the same seed's
    # level without the knock, SuspectScore.caused: a better cell's own windows cross 1.2x of
    # its lower level too): the first correction's can still be, within the cell's accuracy;
    # at least half of them suspect. Against the limit, as issue 50 judges the intervals: every
    # window above 1.2x of it suspect, none suspect below 0.8x of it
    assert r["episode_recall_min"] >= 0.5, r
    limit, timeline = run["accuracy_limit_mm"], run["summary"]["timeline"]
    assert all(w["suspect"] for w in timeline if w["p95_mm"] > 1.2 * limit), timeline
    assert not [w for w in timeline if w["suspect"] and w["p95_mm"] < 0.8 * limit], timeline
    assert (out / "sensor" / "seed-0" / "shift.md").exists()
    md = (out / "shift-knocks.md").read_text()
    assert "| sensor | 1 |" in md and (out / "shift-knocks.png").stat().st_size > 5000


def _covered_until_the_correction(run: dict[str, Any]) -> bool:
    """Every window from the knock's to the first apply after it opened inside the suspect
    interval (the parameters in force in it were the suspect ones)."""
    (first_apply,) = [w for w in run["applied_windows"] if w > run["knock_window"]][:1]
    # the knock's interval: the first not closed before it (a commissioned cell with the
    # robot's repeatability can have an accuracy interval before the knock, its U95 at the limit)
    knock_s = run["settings"]["knock_at_h"] * 3600.0
    (suspect,) = [s for s in run["suspects"] if s["t_end_s"] is None or s["t_end_s"] > knock_s][:1]
    t0_h, t1_h = suspect["t_start_s"] / 3600.0, suspect["t_end_s"] / 3600.0
    timeline = run["summary"]["timeline"]
    opened = [r["t_open_h"] for r in timeline if run["knock_window"] <= r["window"] < first_apply]
    return bool(opened) and all(t0_h <= t <= t1_h for t in opened)


def test_knock_hours_parse_as_a_list() -> None:
    assert hours_list("0.5,0.75,1.5,2.5") == [0.5, 0.75, 1.5, 2.5]
    assert hours_list("4") == [4.0]
    args = build_parser(["experiment"]).parse_args(
        ["experiment", "shift", "--knock-at-h", "0.5,2.5", "--after-h", "1"]
    )
    assert knock_hours(args) == [(0.5, 1.5), (2.5, 3.5)]
    args = build_parser(["experiment"]).parse_args(["experiment", "shift", "--knock-at-h", "0.5,2"])
    assert knock_hours(args) == [(0.5, 8.0), (2.0, 8.0)]


@pytest.mark.parametrize(
    "argv",
    [
        ["--knock-at-h", "0.5,abc"],
        ["--knock-at-h", "0,1"],
        ["--knock-at-h", "-1"],
        ["--knock-at-h", "1,1"],
        ["--knock-at-h", "0.5,"],
        ["--jobs", "0"],
    ],
)
def test_a_bad_knock_hour_list_is_a_usage_error(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Refused where argparse reads it: one line naming the option, exit code 2."""
    with pytest.raises(SystemExit) as exc:
        main(["experiment", "shift", "--out", str(tmp_path / "x"), *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and argv[0] in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["--knock-at-h", "0.5,9"],
        ["--knock-at-h", "2", "--hours", "2"],
        ["--knock-at-h", "1", "--hours", "3", "--after-h", "1"],
        ["--knock-at-h", "1", "--after-h", "0"],
    ],
)
def test_a_knock_hour_outside_its_shift_exits_2(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["experiment", "shift", "--out", str(tmp_path / "x"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert ("--knock-at-h" in err or "--after-h" in err) and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_the_episode_ends_before_a_long_run_back() -> None:
    assert episode_end((), 10) is None
    assert episode_end((5, 6, 7), 10) == 7
    assert episode_end((5, 6, 9, 17), 10) == 17  # 9 windows back between 9 and 19: one episode
    assert episode_end((5, 6, 9, 20, 21), 10) == 9  # 10 back in a row: 20 is not the knock's
    score = SuspectScore(
        bad=(5, 6, 9, 40), covered=(5, 6, 9), covered_before_knock=(), episode_end=9
    )
    assert score.episode_recall == 1.0 and score.recall == 0.75 and score.episode_bad == (5, 6, 9)


def _without_wall_time(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {k: _without_wall_time(v) for k, v in doc.items() if k != "real_s"}
    if isinstance(doc, list):
        return [_without_wall_time(v) for v in doc]
    return doc


@pytest.mark.slow
def test_a_campaign_over_two_knock_hours_in_two_jobs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--knock-at-h 0.15,0.2 --after-h 0.1`: one kind, one seed, two hours; a row per (kind,
    hour), an overall line, every run's seed, kind, hour and reproduce command, each shift
    0.1 h past its knock; --jobs 2 gives the same outputs as --jobs 1 but the wall times."""
    argv = ["experiment", "shift", "--knock-at-h", "0.15,0.2", "--after-h", "0.1"]
    argv += ["--slots-per-window", "2", "--knock", "sensor", "--seeds", "1"]
    docs, mds = [], []
    for jobs in (1, 2):
        out = tmp_path / f"jobs-{jobs}"
        assert main([*argv, "--jobs", str(jobs), "--out", str(out)]) == 0
        docs.append(json.loads((out / "shift-knocks.json").read_text()))
        mds.append((out / "shift-knocks.md").read_text().replace(str(out), "OUT"))
        for h in ("0.15", "0.2"):
            shift = json.loads((out / "sensor" / f"at-{h}h" / "seed-0" / "shift.json").read_text())
            # scored against the same seed without the knock: the windows the knock caused are
            # those above 1.2x of the pre-knock level and of the counterfactual's error
            base, score = shift["baseline_mm"], shift["suspect_score"]
            assert len(base) >= len(shift["summary"]["timeline"])
            assert set(score["caused"]) <= set(score["bad"])
            for w in score["caused"]:
                assert shift["summary"]["timeline"][w - 1]["rmse_mm"] > 1.2 * base[w - 1]
        assert (out / "without-knock" / "seed-0" / "shift.json").exists()
    doc = docs[0]
    assert [(r["knock"], r["knock_at_h"]) for r in doc["rows"]] == [
        ("sensor", [0.15]),
        ("sensor", [0.2]),
    ]
    assert [r["knock_at_h"] for r in doc["overall"]] == [[0.15, 0.2]]
    runs = doc["per_run"]
    assert [(r["knock"], r["knock_at_h"], r["hours"], r["seed"]) for r in runs] == [
        ("sensor", 0.15, 0.25, 0),
        ("sensor", 0.2, 0.3, 0),
    ]
    assert runs[0]["command"].startswith(
        "rvis experiment shift --hours 0.25 --knock-at-h 0.15 --knock sensor"
    )
    assert runs[0]["command"].endswith("--seed 0") and runs[0]["episode_recall"] is not None
    assert runs[0]["command"] in mds[0]
    md = mds[0]
    assert "| sensor | 0.15 | 1 |" in md and "| sensor | 0.2 | 1 |" in md
    assert "| sensor | **all** | 2 |" in md
    assert _without_wall_time(docs[1]) == _without_wall_time(doc)
    assert mds[1] == md
    # the campaign's runs read back and scored again give the figures written
    again = load_campaign(tmp_path / "jobs-1" / "shift-knocks.json")["sensor"]
    assert [run_row(r)["episode_recall"] for r in again] == [r["episode_recall"] for r in runs]
    assert [r.to_json() for r in again] == doc["runs"]["sensor"]


def test_a_campaigns_shifts_run_the_estimator_and_model_the_command_names() -> None:
    """`--estimator` and `--model` reach every shift of a campaign (they once reached only the
    single shift: a campaign "with the sequential estimator" ran the cell file's)."""
    from app.commands.experiment_shift import shift_settings

    argv = ["experiment", "shift", "--knock-at-h", "0.5,0.75", "--after-h", "1"]
    argv += ["--knock", "all", "--seeds", "2", "--estimator", "sequential", "--model", "compliant"]
    args = build_parser(argv).parse_args(argv)
    for knock_h, hours in knock_hours(args):
        s = shift_settings(args, knock_h, hours)
        assert (s.estimator, s.model, s.knock_at_h) == ("sequential", "compliant", knock_h)
    plain = ["experiment", "shift", "--knock-at-h", "0.5"]
    s = shift_settings(build_parser(plain).parse_args(plain), 0.5, 8.0)
    assert s.estimator is None and s.model is None  # the cell file's


@pytest.mark.slow
def test_a_knock_after_a_restart_is_flagged_and_named(cfg: CellConfig, tmp_path: Path) -> None:
    """The service restarted on its state directory three windows before a fixture knock (the
    world and its clock go on): one run's windows, two starts in the service's history, the
    knock flagged within 3 windows, named, and the true RMS within the limit within 6."""
    settings = ShiftSettings(
        hours=0.25, knock_at_h=6 / 60.0, knock="fixture", before_knock="restart"
    )
    result = run_shift(cfg, tmp_path / "state", settings, seed=5)
    assert [r.window for r in result.records] == list(range(1, 16))
    store = Store.read_only(tmp_path / "state" / "rvis.db")
    try:
        kinds = [e["kind"] for e in store.events()]
    finally:
        store.close()
    assert kinds.count("started") == 2 and kinds.count("stopped") == 2
    assert result.knock_window == 7 and result.attribution == "fixture"
    assert result.flagged_after is not None and result.flagged_after <= 3
    assert result.within_limit_after is not None and result.within_limit_after <= 6
