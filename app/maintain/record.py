"""A maintenance procedure's folder and its record in the database: the one of this event
still running (continued), else a new one (numbered after every record so far)."""

from __future__ import annotations

import getpass
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.line.params_store import ParamsStore
from app.line.statedir import StateDir
from app.line.store import Store


def open_record(
    state: StateDir,
    event: str,
    axis: int | None,
    *,
    restart: bool,
    t: float,
    say: Callable[[str], None],
) -> tuple[Path, int]:
    """(the procedure's folder, its maintenance record's id): a running one of this event
    and axis continued, unless `restart` (then it ends 'abandoned' at time t); else a new
    record begun at time t."""
    store = Store(state.db)
    try:
        records = store.maintenance()
        running = [
            r
            for r in records
            if r["status"] == "running" and r["event"] == event and r["axis"] == axis
        ]
        if running and not restart:
            return state.root / running[-1]["folder"], int(running[-1]["id"])
        for r in running:
            store.abandon_maintenance(int(r["id"]), t, "begun again (rvis maintain --restart)")
            say(f"maintenance record {r['id']} abandoned: begun again")
        folder = state.maintenance_folder(len(records) + 1, f"axis{axis}" if axis else event)
        params = ParamsStore(state.root)
        record = store.start_maintenance(
            {
                "t_start": t,
                "event": event,
                "axis": axis,
                "who": getpass.getuser(),
                "folder": str(folder.relative_to(state.root)),
                "version_before": params.current_version(),
                "before": _before(params),
            }
        )
        say(f"maintenance record {record}: {folder}")
        return folder, record
    finally:
        store.close()


def _before(params: ParamsStore) -> dict[str, Any]:
    """The figures before: the version in force and its workspace validation's RMS."""
    doc = params.current_document() or {}
    errors = (doc.get("validation") or {}).get("errors_mm") or []
    rms = (sum(e * e for e in errors) / len(errors)) ** 0.5 if errors else None
    return {"version": doc.get("history_version"), "validation_rmse_mm": rms}
