"""The bodies' AQDEF files in the results directory (issue 49 items 1 and 6): one file a body
and evaluation, written atomically under a stable name; a directory that cannot be written costs
no result: the files wait in the database and all appear, none twice, once it can."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from app.line.body_export import ResultsWriter, file_name
from app.line.store import Store

VALUE = {
    "feature": "H01", "characteristic": "X", "kind": "position", "nominal_mm": 10.0,
    "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": 10.02, "u95_mm": 0.06,
    "decision": "conforming", "reason": "",
}  # fmt: skip


def _evaluation(t: float, **kw: Any) -> dict[str, Any]:
    return {"t": t, "params_version": 1, "statement_u95_mm": 0.08, "reason": "measured",
            "ok": 1, "n_nok": 0, "n_undecided": 0, "n_not_measured": 0, **kw}  # fmt: skip


def test_an_unwritable_directory_loses_no_file_and_writes_none_twice(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    rows = []
    for k in range(20):
        body = {"t": 1e9 + k, "body_id": 100001 + k, "part": "SIM/1"}
        rows.append(store.add_body(body, _evaluation(1e9 + k), [VALUE], []))
    folder = tmp_path / "spc" / "import"
    folder.parent.mkdir()
    folder.write_text("not a folder")  # the share's mount point is a file: cannot write
    writer = ResultsWriter(folder, ("7", "station 7"), "a part")
    written, why = writer.export_pending(store, 2e9)
    assert written == 0 and str(folder) in why
    assert len(store.unexported()) == 20  # every body still waits
    folder.unlink()  # the share is back
    assert writer.export_pending(store, 2e9) == (20, "")
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(file_name("SIM/1", 100001 + k, 0) for k in range(20))
    assert names[0] == "SIM_1_100001_e0.dfq"
    assert writer.export_pending(store, 2e9) == (0, "")  # nothing twice
    # a body computed again: a new file beside the first, marked so in its values' text
    store.add_evaluation(rows[3], _evaluation(1e9 + 50, reason="re-evaluated", suspect_id=None),
                         [{**VALUE, "measured_mm": 10.001}])  # fmt: skip
    assert writer.export_pending(store, 2e9) == (1, "")
    again = (folder / "SIM_1_100004_e1.dfq").read_bytes().decode("ascii")
    assert "K0001/1 10.001000" in again and "computed again (evaluation 1)" in again
    assert "K1081 7\r\n" in again and "K1002 a part\r\n" in again
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # no temporary left
    store.close()
