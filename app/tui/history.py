"""History for the operator's screens, read from the service's database read-only
(`mode=ro`: the TUI can never write, and never takes the writer's lock). Every method opens its
own short connection, so it can run in a worker thread while the service keeps writing."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any


class HistoryReader:
    """Recent measurements, calibrations, alarms and events of one state directory."""

    def __init__(self, db_path: str | Path) -> None:
        self.db_path = Path(db_path)

    def _query(self, sql: str, args: tuple[Any, ...] = ()) -> list[dict[str, Any]]:
        if not self.db_path.exists():
            return []
        uri = f"file:{self.db_path}?mode=ro"
        con = sqlite3.connect(uri, uri=True, timeout=1.0)
        try:
            con.row_factory = sqlite3.Row
            return [dict(r) for r in con.execute(sql, args)]
        except sqlite3.OperationalError:
            return []  # a database still being created or migrated: nothing to show yet
        finally:
            con.close()

    def measurements(self, limit: int = 200, sphere: str | None = None) -> list[dict[str, Any]]:
        where, args = ("WHERE sphere = ?", (sphere,)) if sphere else ("", ())
        return self._query(
            f"SELECT * FROM measurements {where} ORDER BY id DESC LIMIT ?", (*args, limit)
        )

    def calibrations(self, limit: int = 100) -> list[dict[str, Any]]:
        return self._query("SELECT * FROM calibrations ORDER BY id DESC LIMIT ?", (limit,))

    def alarms(self, limit: int = 200) -> list[dict[str, Any]]:
        return self._query("SELECT * FROM alarms ORDER BY id DESC LIMIT ?", (limit,))

    def events(self, limit: int = 500, text: str = "") -> list[dict[str, Any]]:
        if text:
            return self._query(
                "SELECT * FROM events WHERE kind LIKE ? OR detail LIKE ? ORDER BY id DESC LIMIT ?",
                (f"%{text}%", f"%{text}%", limit),
            )
        return self._query("SELECT * FROM events ORDER BY id DESC LIMIT ?", (limit,))
