"""`rvis results` (issue 49 item 2, issue 51's "how sure is the measurement of body 100012?"):
the bodies' results read from the state database: each body's newest values with their U95 and
decisions, suspect when measured inside a suspect interval and not computed again with its
correction; JSON and CSV exports equal to the database's; bad input refused in one line."""

from __future__ import annotations

import csv
import io
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.commands.cli import main
from app.line.statedir import StateDir
from app.line.store import Store

VALUE = {
    "feature": "H01", "characteristic": "X", "kind": "position", "nominal_mm": 10.0,
    "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": 10.02, "u95_mm": 0.06,
    "decision": "conforming", "reason": "",
}  # fmt: skip
#: 2026-11-29T06:00:00Z: a day above 12, which no reader can take for a month
T0 = datetime(2026, 11, 29, 6, 0, tzinfo=UTC).timestamp()
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
    for k, t in enumerate((T0 + 100.0, T0 + 200.0, T0 + 300.0)):
        body = {"t": t, "body_id": 100011 + k, "part": "P-1", "window": k}
        raw = [{"feature": "H01", "q_deg": [0.0] * 6, "temp_c": None, "sheet": None,
                "edges": None, "refused": ""}]  # fmt: skip
        row = store.add_body(body, _evaluation(t), [VALUE, NOT_MEASURED], raw)
    sid = store.open_suspect(
        {"t_start": T0 + 150.0, "onset_id": 1, "params_version": 1, "text": "sensor mount moved"}
    )
    store.update_suspect(sid, t_end=T0 + 350.0, end_reason="step", end_version=2)
    store.add_evaluation(
        row, _evaluation(T0 + 400.0, params_version=2, suspect_id=sid, reason="re-evaluated"),
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


def test_the_dfq_reads_back_in_an_independent_reader(state: StateDir, tmp_path: Path) -> None:
    """aqdefreader (PyPI) parses the values, limits, units and times (its own file reading
    leaves the file open: the test reads it and hands the lines to its parser); the body ids
    (K0014, which it does not read) from the file's lines."""
    from aqdefreader import DfqFile

    (state.root / "features.toml").write_text('part = "P-1"\ndescription = "two features"\n')
    out = tmp_path / "out"
    argv = ["results", "export", "--format", "dfq", "--out", str(out)]
    assert main([*argv, "--state-dir", str(state.root)]) == 0
    path = out / "results.dfq"
    raw = path.read_bytes()
    assert raw.count(b"\r\n") == raw.count(b"\n") and raw.isascii()
    part = DfqFile(raw.decode("ascii").splitlines()).get_part(0)  # its parser, our read
    assert part.get_data("K1001") == "P-1" and part.get_data("K1002") == "two features"
    x, d = part.get_characteristic_by_index(1), part.get_characteristic_by_index(2)
    assert x.get_data("K2001") == "H01.X" and d.get_data("K2001") == "H01.D"
    assert float(x.get_data("K2101")) == 10.0 and float(x.get_data("K2110")) == 9.5
    assert float(x.get_data("K2111")) == 10.5 and x.get_data("K2142") == "mm"
    values = [(float(m.value), m.attribute, m.datetime.isoformat()) for m in x.get_measurements()]
    assert values == [
        (10.02, 0, "2026-11-29T06:01:40"),  # as measured
        (10.02, 129, "2026-11-29T06:03:20"),  # inside the interval: shown, not calculated
        (10.001, 0, "2026-11-29T06:05:00"),  # computed again with the correction
    ]
    assert [m.attribute for m in d.get_measurements()] == [255, 255, 255]  # not measured
    ids = [line.split()[1] for line in raw.decode().splitlines() if line.startswith("K0014/1 ")]
    assert ids == ["100011", "100012", "100013"]
    texts = [line for line in raw.decode().splitlines() if line.startswith("K0009/1 ")]
    assert texts[0] == "K0009/1 U95 0.060 mm; conforming"
    assert texts[2].endswith("computed again (evaluation 1)")


def test_capability_over_the_bodies_not_suspect(
    state: StateDir, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["results", "capability", "--json", "--state-dir", str(state.root)]
    assert main(argv) == 0
    (x,) = [r for r in json.loads(capsys.readouterr().out) if r["characteristic"] == "X"]
    # the suspect body's value is left out: 10.02 and 10.001 remain
    assert x["n"] == 2 and x["mean_mm"] == pytest.approx(10.0105)
    sd = float(np.std([10.02, 10.001], ddof=1))
    assert x["cp"] == pytest.approx(1.0 / (6 * sd))
    assert x["cpk"] == pytest.approx((10.5 - 10.0105) / (3 * sd))


def test_a_restored_backup_holds_the_bodies_and_exports_the_same_files(
    state: StateDir, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Retention (issue 49 item 6): the bodies, their evaluations, values and raw points are in
    `rvis.db`, which `rvis state backup` copies with the feature plan; `rvis results export`
    from the restored directory writes the same files, byte for byte."""
    (state.root / "features.toml").write_text('part = "P-1"\ndescription = "two features"\n')
    store = Store(state.db)
    points = np.arange(30.0).reshape(10, 3) * 0.25
    raw = [{"feature": "H01", "q_deg": [1.0] * 6, "temp_c": 21.5, "sheet": points,
            "edges": points[:4], "refused": ""}]  # fmt: skip
    store.add_body(
        {"t": T0 + 500.0, "body_id": "WDB-7", "part": "P-1"}, _evaluation(T0 + 500.0),
        [VALUE, NOT_MEASURED], raw,
    )  # fmt: skip
    store.close()
    backup, restored = tmp_path / "backup", StateDir(tmp_path / "restored")
    assert main(["state", "backup", str(backup), "--state-dir", str(state.root)]) == 0
    assert main(["state", "restore", str(backup), "--state-dir", str(restored.root)]) == 0
    capsys.readouterr()

    def held(paths: StateDir) -> list[Any]:
        s = Store.read_only(paths.db)
        try:
            return [
                (b, s.body_evaluations(b["id"]), s.body_values(b["id"], 0),
                 [{k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in r.items()}
                  for r in s.body_raw(b["id"])])
                for b in s.bodies()
            ]  # fmt: skip
        finally:
            s.close()

    before, after = held(state), held(restored)
    assert after == before and len(after) == 4 and after[3][3][0]["sheet"] == points.tolist()
    for fmt in ("dfq", "csv", "json"):
        outs = []
        for paths in (state, restored):
            out = tmp_path / f"{fmt}-{paths.root.name}"
            argv = ["results", "export", "--format", fmt, "--out", str(out)]
            assert main([*argv, "--state-dir", str(paths.root)]) == 0
            outs.append((out / f"results.{fmt}").read_bytes())
        assert outs[0] == outs[1] and b"WDB-7" in outs[0], fmt
