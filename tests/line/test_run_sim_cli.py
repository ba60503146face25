"""`rvis run --sim`: the service on the simulated line, through the real drivers over loopback,
stopped after N windows with a summary that the database and the truth confirm."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from app.commands.cli import main


def test_run_sim_geometric_windows_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = tmp_path / "state"
    code = main(
        ["run", "--sim", "--geometric", "--windows", "3", "--json", "--state-dir", str(state)]
    )
    out = capsys.readouterr().out
    assert code == 0
    summary = json.loads(out)
    assert summary["windows"] == 3 and summary["overruns"] == 0
    assert summary["measurements"] + summary["rejected"] == 3
    assert 0.0 < summary["true_rmse_start_mm"] < 0.3  # the commissioning calibration
    assert len(summary["timeline"]) == 3
    with sqlite3.connect(state / "rvis.db") as db:
        rows = db.execute("SELECT count(*) FROM measurements WHERE status = 'ok'").fetchone()[0]
    assert rows == summary["measurements"]
    assert (state / "params" / "current.json").is_file()
    assert not (state / "rvis.sock").exists()  # the control socket is gone with the service
    # the simulated part type's features put there, and its bodies measured (issue 48)
    assert (state / "features.toml").is_file()
    with sqlite3.connect(state / "rvis.db") as db:
        values = db.execute("SELECT count(*) FROM body_values WHERE measured_mm IS NOT NULL")
        assert values.fetchone()[0] > 0
        evaluations = db.execute("SELECT ok, n_undecided FROM body_evaluations").fetchall()
    # the summary counts the bodies the store holds (one evaluation each: no correction)
    assert summary["bodies"] == len(evaluations) == 3
    assert summary["bodies_nok"] == sum(not ok for ok, _ in evaluations)
    assert summary["bodies_undecided"] == sum(n > 0 for _, n in evaluations)
    assert summary["bodies_reevaluated"] == 0


def test_sim_options_need_sim(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--windows", "3"]) == 2
    assert "need --sim" in capsys.readouterr().err


def test_the_state_directory_supplies_the_cell_file_and_the_plan(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`rvis run --sim --state-dir S` reads S/cell.toml and S/plan.json (as `rvis commission`
    leaves them) when --cell and --plan do not name others; each is checked as it is read."""
    state = tmp_path / "state"
    state.mkdir()
    run = ["run", "--sim", "--geometric", "--windows", "1", "--state-dir", str(state)]
    (state / "cell.toml").write_text("[service]\nevery_n = -3\n")
    assert main(run) == 2
    err = capsys.readouterr().err
    assert "cell.toml" in err and "every_n" in err
    (state / "cell.toml").write_text("[simulation]\nseed = 5\n")
    (state / "plan.json").write_text("{ not a plan")
    assert main(run) == 2
    assert "plan.json" in capsys.readouterr().err
    assert main([*run, "--plan", str(tmp_path / "none.json")]) == 2  # --plan names another
    assert "none.json" in capsys.readouterr().err


def test_a_restarted_simulated_line_continues_the_services_clock(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The simulated line runs ahead of the wall clock; run again on the same state directory
    its clock starts where the history ends, so that every record (the Calibrations screen's
    versions and calibrations, the measurements) is on one timeline (issue 30 item 8)."""
    state = tmp_path / "state"
    run = ["run", "--sim", "--geometric", "--windows", "3", "--json", "--state-dir", str(state)]
    assert main(run) == 0
    with sqlite3.connect(state / "rvis.db") as db:
        first_last = db.execute("SELECT MAX(t) FROM events").fetchone()[0]
    assert main(run) == 0
    capsys.readouterr()
    with sqlite3.connect(state / "rvis.db") as db:
        times = [r[0] for r in db.execute("SELECT t FROM events ORDER BY id")]
        started = db.execute("SELECT t FROM events WHERE kind = 'started' ORDER BY id").fetchall()
    assert len(started) == 2 and started[1][0] > first_last
    assert times == sorted(times)  # never back in time


def test_a_restarted_simulated_line_continues_its_world(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Run again on the same state directory, the simulated line continues the world the last
    run left (issue 40 item 3): the cell as warm as it was (not cold at its ambient again, which
    the service would flag as a step of the cell's), and the PLC's body count goes on (no body
    id given twice)."""
    state = tmp_path / "state"
    state.mkdir()
    (state / "cell.toml").write_text("[simline]\nwarmup_k = 8.0\nwarmup_tau_s = 300.0\n")
    run = ["run", "--sim", "--geometric", "--windows", "4", "--json", "--state-dir", str(state)]
    assert main(run) == 0
    first = [r["temp_c"] for r in json.loads(capsys.readouterr().out)["timeline"]]
    with sqlite3.connect(state / "rvis.db") as db:
        bodies_1 = [r[0] for r in db.execute("SELECT body_id FROM windows ORDER BY id")]
    assert main(run) == 0
    second = [r["temp_c"] for r in json.loads(capsys.readouterr().out)["timeline"]]
    with sqlite3.connect(state / "rvis.db") as db:
        bodies = [r[0] for r in db.execute("SELECT body_id FROM windows ORDER BY id")]
    assert first[-1] > first[0] + 1.0  # it warmed up (4 windows of 60 s, tau 300 s)
    assert second[0] >= first[-1] and second[-1] > second[0]  # warm as left, warming on
    assert len(bodies) == 2 * len(bodies_1) == 8
    assert len(set(bodies)) == len(bodies) and bodies == sorted(bodies)


def test_the_summary_says_which_windows_bodies_are_suspect_as_state_suspects_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 51: the summary's timeline gave `"suspect": false` for every window while `rvis
    state suspects` put most of those bodies in suspect intervals. Each window names its body
    (the PLC's id) and is suspect exactly when `rvis state suspects` lists that body; a limit
    no statement meets makes every window's body suspect, the first one's included."""
    state = tmp_path / "state"
    state.mkdir()
    (state / "cell.toml").write_text("[service]\naccuracy_limit_mm = 0.01\n")
    run = ["run", "--sim", "--geometric", "--windows", "5", "--json", "--state-dir", str(state)]
    assert main(run) == 0
    timeline = json.loads(capsys.readouterr().out)["timeline"]
    assert main(["state", "suspects", "--json", "--state-dir", str(state)]) == 0
    listed = {b for s in json.loads(capsys.readouterr().out) for b in s["bodies"]}
    bodies = [r["body"] for r in timeline]
    assert len(set(bodies)) == 5 and None not in bodies
    assert {r["body"] for r in timeline if r["suspect"]} == listed & set(bodies)
    assert all(r["suspect"] for r in timeline)


def test_a_simulated_directory_keeps_its_seed_and_path(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 51: a directory made by `rvis run --sim --geometric --seed 44`, run again without
    --seed, ran another world (seed 0, rendered) on seed 44's parameters: 4.8 mm off and held
    for maintenance. As a commissioned directory does, it keeps its seed and measuring path,
    and another --seed is refused in one line (exit 2)."""
    state = tmp_path / "state"
    first = ["run", "--sim", "--geometric", "--seed", "44", "--windows", "1"]
    assert main([*first, "--json", "--state-dir", str(state)]) == 0
    capsys.readouterr()
    again = ["run", "--sim", "--windows", "1", "--state-dir", str(state)]
    assert main(again) == 0
    assert "rvis run --sim: seed 44, geometric measurements" in capsys.readouterr().err
    assert main([*again, "--seed", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed 44" in err[0] and "--seed 0 is another cell" in err[0]
    with sqlite3.connect(state / "rvis.db") as db:
        started = db.execute("SELECT COUNT(*) FROM events WHERE kind = 'started'").fetchone()
    assert started[0] == 2  # the refused run started nothing


def test_run_sim_no_bodies_measures_spheres_only(tmp_path: Path) -> None:
    """`--no-bodies`: no feature plan put in the state directory and no body measured; the
    flag without --sim is refused like the other simulation options."""
    state = tmp_path / "state"
    run = ["run", "--sim", "--geometric", "--windows", "2", "--json", "--no-bodies"]
    assert main([*run, "--state-dir", str(state)]) == 0
    assert not (state / "features.toml").exists()
    with sqlite3.connect(state / "rvis.db") as db:
        assert db.execute("SELECT count(*) FROM body_values").fetchone()[0] == 0
    assert main(["run", "--no-bodies", "--state-dir", str(state)]) == 2
