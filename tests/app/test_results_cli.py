"""`rvis results` (issue 49 item 2, issue 51's "how sure is the measurement of body 100012?"):
the bodies' results read from the state database: each body's newest values with their U95 and
decisions, suspect when measured inside a suspect interval and not computed again with its
correction; JSON and CSV exports equal to the database's; bad input refused in one line."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.line.statedir import StateDir
from app.line.store import Store

VALUE = {
    "feature": "H01", "characteristic": "X", "kind": "position", "nominal_mm": 10.0,
    "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": 10.02, "u95_mm": 0.06,
    "decision": "conforming", "reason": "",
}  # fmt: skip
NOT_MEASURED = {**VALUE, "characteristic": "D", "kind": "size", "nominal_mm": 8.0,
                "lower_mm": 7.8, "upper_mm": 8.2, "measured_mm": None, "u95_mm": None,
                "decision": "not measured", "reason": "edge_points: 3 edge points"}  # fmt: skip


def _evaluation(t: float, **kw: Any) -> dict[str, Any]:
    return {"t": t, "params_version": 1, "statement_u95_mm": 0.08, "reason": "measured",
            "ok": 0, "n_nok": 0, "n_undecided": 0, "n_not_measured": 1, **kw}  # fmt: skip


@pytest.fixture()
def state(tmp_path: Path) -> StateDir:
    """Three bodies; the second inside a closed suspect interval (not computed again), the
    third inside it and computed again with its correction."""
    paths = StateDir(tmp_path / "state")
    paths.root.mkdir()
    store = Store(paths.db)
    for k, t in enumerate((100.0, 200.0, 300.0)):
        body = {"t": t, "body_id": 100011 + k, "part": "P-1", "window": k}
        raw = [{"feature": "H01", "q_deg": [0.0] * 6, "temp_c": None, "sheet": None,
                "edges": None, "refused": ""}]  # fmt: skip
        row = store.add_body(body, _evaluation(t), [VALUE, NOT_MEASURED], raw)
    sid = store.open_suspect(
        {"t_start": 150.0, "onset_id": 1, "params_version": 1, "text": "sensor mount moved"}
    )
    store.update_suspect(sid, t_end=350.0, end_reason="step", end_version=2)
    store.add_evaluation(
        row, _evaluation(400.0, params_version=2, suspect_id=sid, reason="re-evaluated"),
        [{**VALUE, "measured_mm": 10.001}, NOT_MEASURED],
    )  # fmt: skip
    store.close()
    return paths


def test_list_and_show_say_what_each_value_is_and_how_sure(
    state: StateDir, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["results", "list", "--json", "--state-dir", str(state.root)]) == 0
    recs = json.loads(capsys.readouterr().out)
    assert [r["body"] for r in recs] == [100011, 100012, 100013]
    assert [r["suspect_interval"] is not None for r in recs] == [False, True, False]
    assert recs[2]["reevaluated"] and recs[2]["values"][0]["measured_mm"] == 10.001
    assert recs[1]["values"][0]["suspect"] and not recs[1]["values"][1]["suspect"]
    assert main(["results", "show", "100012", "--state-dir", str(state.root)]) == 0
    text = capsys.readouterr().out
    assert "SUSPECT" in text and "U95 0.080 mm" in text and "0.060" in text
    assert "not measured: edge_points" in text


def test_exports_equal_the_database(
    state: StateDir, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = ["results", "export", "--format", "csv", "--out", str(out)]
    assert main([*argv, "--state-dir", str(state.root)]) == 0
    assert "written" in capsys.readouterr().out
    rows = list(csv.DictReader(io.StringIO((out / "results.csv").read_text())))
    assert len(rows) == 6 and rows[0]["body"] == "100011" and rows[0]["u95_mm"] == "0.06"
    assert rows[1]["measured_mm"] == "" and rows[1]["decision"] == "not measured"
    argv = ["results", "export", "--format", "json", "--body", "100013"]
    assert main([*argv, "--state-dir", str(state.root)]) == 0
    (rec,) = json.loads(capsys.readouterr().out)
    keys = {"feature", "characteristic", "nominal_mm", "measured_mm", "lower_mm", "upper_mm",
            "u95_mm", "decision", "suspect"}  # fmt: skip
    assert keys <= set(rec["values"][0]) and rec["time_utc"].endswith("+00:00")


def test_bad_input_is_one_line(
    state: StateDir, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["results", "show", "42", "--state-dir", str(state.root)]) == 2
    assert main(["results", "list", "--state-dir", str(tmp_path / "none")]) == 2
    assert main(["results", "list", "--since", "yesterday", "--state-dir", str(state.root)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all("Traceback" not in e for e in err)
    assert "no body '42'" in err[0] and "no rvis.db" in err[1] and "--since" in err[2]
