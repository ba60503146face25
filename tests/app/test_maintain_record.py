"""A maintenance procedure's record (app/maintain/record.py): continued while it runs, begun
again with --restart, the earlier one then abandoned, never left 'running'."""

from __future__ import annotations

from pathlib import Path

from app.line.statedir import StateDir
from app.line.store import Store
from app.maintain.record import open_record


def test_a_restart_abandons_the_running_record_and_begins_a_new_one(tmp_path: Path) -> None:
    state = StateDir(tmp_path / "state")
    state.root.mkdir()
    Store(state.db).close()
    said: list[str] = []
    first, a = open_record(state, "axis", 3, restart=False, t=10.0, say=said.append)
    again, b = open_record(state, "axis", 3, restart=False, t=20.0, say=said.append)
    assert (again, b) == (first, a)  # continued
    _other, c = open_record(state, "sensor", None, restart=False, t=25.0, say=said.append)
    assert c != a  # another event's procedure is its own
    new, d = open_record(state, "axis", 3, restart=True, t=30.0, say=said.append)
    assert d not in (a, c) and new != first
    store = Store.read_only(state.db)
    try:
        by_id = {r["id"]: r for r in store.maintenance()}
    finally:
        store.close()
    assert by_id[a]["status"] == "abandoned" and by_id[a]["t_end"] == 30.0
    assert by_id[c]["status"] == "running" and by_id[d]["status"] == "running"
    assert any("abandoned" in line for line in said)
