"""History for the operator's screens, read from the service's database read-only
(`mode=ro`: the TUI can never write, and never takes the writer's lock). Every method opens its
own short connection, so it can run in a worker thread while the service keeps writing. Rows
come back as the screens name things (`utc`, `sphere`, `text`), whatever the table calls them.
"""

from __future__ import annotations

import json
import sqlite3
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.line.store import suspect_rows


def _utc(t: Any) -> str:
    if not isinstance(t, int | float):
        return ""
    return datetime.fromtimestamp(float(t), UTC).isoformat(timespec="seconds")


def _doc(text: Any) -> dict[str, Any]:
    try:
        doc = json.loads(text or "{}")
    except ValueError:
        return {}
    return doc if isinstance(doc, dict) else {}


class HistoryReader:
    """Recent measurements, calibrations, alarms, suspect intervals and events of one state
    directory."""

    def __init__(self, db_path: str | Path) -> None:
        self.db_path = Path(db_path)

    def _query(self, sql: str, args: tuple[Any, ...] = ()) -> list[dict[str, Any]]:
        if not self.db_path.exists():
            return []
        con = sqlite3.connect(f"file:{self.db_path}?mode=ro", uri=True, timeout=1.0)
        try:
            con.row_factory = sqlite3.Row
            return [dict(r) for r in con.execute(sql, args)]
        except sqlite3.OperationalError:
            return []  # a database still being created or migrated: nothing to show yet
        finally:
            con.close()

    def measurements(self, limit: int = 200, sphere: str | None = None) -> list[dict[str, Any]]:
        where, args = ("WHERE target = ?", (sphere,)) if sphere else ("", ())
        rows = self._query(
            "SELECT id, t, target, status, reason, residual_mm FROM measurements "
            f"{where} ORDER BY id DESC LIMIT ?",
            (*args, limit),
        )
        return [{**r, "utc": _utc(r["t"]), "sphere": r["target"]} for r in rows]

    def calibrations(self, limit: int = 100) -> list[dict[str, Any]]:
        rows = self._query(
            "SELECT id, t, status, rms_mm, holdout_rms_mm, reason, version FROM calibrations "
            "ORDER BY id DESC LIMIT ?",
            (limit,),
        )
        return [{**r, "utc": _utc(r["t"]), "gates": r["reason"]} for r in rows]

    def applied(self, limit: int = 100) -> list[dict[str, Any]]:
        """The parameter versions put in force (newest first): a rollback picks one."""
        rows = self._query(
            "SELECT version, t, source, calibration_id FROM applied ORDER BY id DESC LIMIT ?",
            (limit,),
        )
        return [{**r, "utc": _utc(r["t"])} for r in rows]

    def alarms(self, limit: int = 200) -> list[dict[str, Any]]:
        rows = self._query("SELECT * FROM alarms ORDER BY id DESC LIMIT ?", (limit,))
        return [
            {
                **r,
                "text": r.get("message", ""),
                "raised_utc": _utc(r.get("t_raised")),
                "acked_utc": _utc(r.get("t_acked")),
                "cleared_utc": _utc(r.get("t_cleared")),
                "shelved_until_utc": _utc(r.get("shelved_until")),
            }
            for r in rows
        ]

    def suspects(self, limit: int = 50) -> list[dict[str, Any]]:
        """Suspect intervals after steps, newest first (app/line/step.py), each with the bodies
        measured in it (the store's query, app.line.store.suspect_rows)."""
        if not self.db_path.exists():
            return []
        con = sqlite3.connect(f"file:{self.db_path}?mode=ro", uri=True, timeout=1.0)
        try:
            rows = suspect_rows(con, last=limit)[::-1]
        except sqlite3.OperationalError:
            return []  # a database still being created or migrated: nothing to show yet
        finally:
            con.close()
        return [
            {
                **r,
                "start_utc": _utc(r["t_start"]),
                "end_utc": _utc(r["t_end"]),
                "group": r["group_name"],
            }
            for r in rows
        ]

    def maintenance(self, limit: int = 50) -> list[dict[str, Any]]:
        """The maintenance procedures (`rvis maintain`, app/maintain/), newest first: running
        or done, with their versions and figures before and after (none in an older
        database: no such table)."""
        rows = self._query("SELECT * FROM maintenance ORDER BY id DESC LIMIT ?", (limit,))
        return [
            {
                **r,
                "start_utc": _utc(r["t_start"]),
                "end_utc": _utc(r["t_end"]),
                "before": _doc(r.get("before")),
                "after": _doc(r.get("after")),
            }
            for r in rows
        ]

    def events(self, limit: int = 500, text: str = "") -> list[dict[str, Any]]:
        if text:
            rows = self._query(
                "SELECT id, t, kind, data FROM events WHERE kind LIKE ? OR data LIKE ? "
                "ORDER BY id DESC LIMIT ?",
                (f"%{text}%", f"%{text}%", limit),
            )
        else:
            rows = self._query(
                "SELECT id, t, kind, data FROM events ORDER BY id DESC LIMIT ?", (limit,)
            )
        return [{**r, "utc": _utc(r["t"]), "detail": r["data"]} for r in rows]
