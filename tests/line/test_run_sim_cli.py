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


def test_sim_options_need_sim(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--windows", "3"]) == 2
    assert "need --sim" in capsys.readouterr().err
