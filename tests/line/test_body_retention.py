"""Retention of the bodies (issue 49 item 6): the bodies older than `[results] keep_days` are
deleted from the database with their evaluations, values and raw data by the service's
retention pass, and the files rvis wrote of them removed from the results directory; a body an
open suspect interval holds, or one whose file waits to be written, is kept (nothing lost), and
so is a file a later measurement of the same body has written under the same name."""

from __future__ import annotations

import logging
import sqlite3
from dataclasses import replace
from pathlib import Path
from typing import Any

from app.config import load_cell
from app.line.body_export import ResultsWriter, file_name, retain_bodies
from app.line.settings import ServiceSettings
from app.line.store import Store
from tests.line.helpers import make_line

DAY_S = 86400.0
NOW = 2e9
LOG = logging.getLogger("test")
VALUE = {
    "feature": "H01", "characteristic": "X", "kind": "position", "nominal_mm": 10.0,
    "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": 10.02, "u95_mm": 0.06,
    "decision": "conforming", "reason": "",
}  # fmt: skip
RAW = {"feature": "H01", "q_deg": [0.0] * 6, "temp_c": 20.0, "sheet": None, "edges": None}


def _evaluation(t: float, **kw: Any) -> dict[str, Any]:
    return {"t": t, "params_version": 1, "statement_u95_mm": 0.08, "reason": "measured",
            "ok": 1, "n_nok": 0, "n_undecided": 0, "n_not_measured": 0, **kw}  # fmt: skip


def _body(store: Store, age_days: float, body_id: Any, part: str = "P-1") -> int:
    t = NOW - age_days * DAY_S
    body = {"t": t, "body_id": body_id, "part": part, "window": 1}
    return store.add_body(body, _evaluation(t), [VALUE], [RAW])


def _rows(db: Path, table: str) -> int:
    with sqlite3.connect(db) as con:
        return int(con.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0])


def _settings(folder: Path | None, keep_days: float = 365.0) -> ServiceSettings:
    return ServiceSettings(results_dir=folder, results_keep_days=keep_days)


def test_the_cell_file_sets_the_days(tmp_path: Path) -> None:
    from app.line.settings import from_cell

    cell = tmp_path / "cell.toml"
    cell.write_text('[results]\ndir = "out"\nkeep_days = 30\n')
    s = from_cell(load_cell(cell), tmp_path)
    assert s.results_keep_days == 30.0 and s.results_dir == tmp_path / "out"
    assert ServiceSettings().results_keep_days == 365.0


def test_old_bodies_go_with_their_files_and_the_held_ones_stay(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    folder = tmp_path / "results"
    writer = ResultsWriter(folder, ("7", "station 7"))
    old = [_body(store, 400.0 + k, 100001 + k) for k in range(5)]  # 400-404 days old
    recent = _body(store, 10.0, 100010)
    again = _body(store, 20.0, 100001)  # body 100001 measured again: its file has the name now
    store.add_evaluation(old[1], _evaluation(NOW - 399 * DAY_S, reason="re-evaluated"), [VALUE])
    held = _body(store, 390.0, 100020)  # inside a suspect interval still open (below)
    assert writer.export_pending(store, NOW) == (9, "")
    waiting = _body(store, 500.0, 100030)  # its file not written yet: the folder was away
    store.open_suspect({"t_start": NOW - 398 * DAY_S, "onset_id": 1, "params_version": 1})
    alien = folder / "plant-notes.txt"  # not a name rvis writes: never touched
    alien.write_text("x")
    (folder / file_name("P-1", 100003, 0)).unlink()  # the plant's import took it: fine

    # the 5 old bodies go; 4 files: 100002's two (as measured, computed again), 100004's,
    # 100005's; 100001's file is its later measurement's and stays
    assert retain_bodies(store, _settings(folder), NOW, LOG) == (5, 4)
    assert [b["id"] for b in store.bodies()] == [recent, again, held, waiting]
    names = {p.name for p in folder.iterdir()}
    assert names == {alien.name, *(file_name("P-1", i, 0) for i in (100001, 100010, 100020))}
    assert store.body_values(old[1]) == [] and list(store.body_raw(old[1])) == []
    assert store.body_evaluations(old[1]) == []
    assert retain_bodies(store, _settings(folder), NOW, LOG) == (0, 0)  # nothing twice
    store.close()
    for table in ("bodies", "body_evaluations", "body_raw", "body_values"):
        assert _rows(tmp_path / "rvis.db", table) == 4, table


def test_without_a_results_directory_nothing_waits_and_0_keeps_them(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    rows = [_body(store, 400.0, 100001), _body(store, 1.0, 100002)]
    assert retain_bodies(store, _settings(None, keep_days=0.0), NOW, LOG) == (0, 0)
    assert retain_bodies(store, _settings(None, keep_days=1000.0), NOW, LOG) == (0, 0)
    # no folder: no file ever waits, the old body goes
    assert retain_bodies(store, _settings(None), NOW, LOG) == (1, 0)
    assert [b["id"] for b in store.bodies()] == rows[1:]
    store.close()


def test_files_that_cannot_be_removed_keep_their_bodies_until_they_can(tmp_path: Path) -> None:
    from tests.unwritable import unwritable

    store = Store(tmp_path / "rvis.db")
    folder = tmp_path / "results"
    rows = [_body(store, 400.0 + k, 100001 + k) for k in range(3)]
    ResultsWriter(folder, ("7", "s")).export_pending(store, NOW)
    with unwritable(folder):
        assert retain_bodies(store, _settings(folder), NOW, LOG) == (0, 0)
        assert [b["id"] for b in store.bodies()] == rows
    assert retain_bodies(store, _settings(folder), NOW, LOG) == (3, 3)
    assert list(folder.iterdir()) == [] and store.bodies() == []
    store.close()


def test_the_service_pass_deletes_the_old_bodies(tmp_path: Path) -> None:
    ln = make_line(tmp_path)
    folder = tmp_path / "results"
    ln.service.settings = replace(ln.service.settings, results_dir=folder, results_keep_days=90.0)
    store = ln.service.store
    now = ln.clock.time()
    old, new = (
        store.add_body({"t": t, "body_id": i, "part": "P-1"}, _evaluation(t), [VALUE], [RAW])
        for i, t in ((7, now - 100 * DAY_S), (8, now - 10 * DAY_S))
    )
    ResultsWriter(folder, ("7", "s")).export_pending(store, now)
    try:
        ln.start()
        ln.windows(1)
        left = [b["id"] for b in store.bodies()]
    finally:
        ln.close()
    assert left == [new] and old not in left
    assert sorted(p.name for p in folder.iterdir()) == [file_name("P-1", 8, 0)]
