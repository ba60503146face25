"""History for the operator's screens, read from the service's database read-only
(`mode=ro`: the TUI can never write, and never takes the writer's lock). Every method opens its
own short connection, so it can run in a worker thread while the service keeps writing. Rows
come back as the screens name things (`utc`, `sphere`, `text`), whatever the table calls them.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.inspect.spc import BASELINE_BODIES, BASELINE_N, IndividualsChart, add_values
from app.line.body_results import records
from app.line.interval_store import suspect_rows
from app.line.store import StorageError, Store


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
        #: the SPC charts of the first bodies, by their (row, evaluation): read once
        self._charts: tuple[list[tuple[int, int]], list[dict[str, Any]]] = ([], [])

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

    def bodies(self, last: int) -> list[dict[str, Any]]:
        """The last bodies measured, oldest first, each its newest evaluation with its values
        and whether they are suspect (app.line.body_results.records, as `rvis results`)."""
        return self._with_store(lambda store: records(store, last=last))

    def charts(self) -> list[dict[str, Any]]:
        """The service's SPC chart of each characteristic (app.inspect.spc): key, centre_mm,
        sigma_mm, lcl_mm, ucl_mm (None before its baseline is complete), baseline_n; replayed
        from the first bodies as the service replays them at its start."""
        return self._with_store(self._read_charts)

    def _read_charts(self, store: Store) -> list[dict[str, Any]]:
        first = store.bodies(first=BASELINE_BODIES)
        ids = [(int(b["id"]), int(b["evaluation"])) for b in first]
        if ids == self._charts[0]:
            return self._charts[1]
        charts: dict[str, IndividualsChart] = {}
        for b in first:
            add_values(charts, b["body_id"], store.body_values(int(b["id"])))
        out = []
        for key, c in charts.items():
            done = len(c.baseline) == BASELINE_N
            lcl, ucl = c.limits_mm
            out.append(
                {
                    "key": key,
                    "centre_mm": c.centre if done else None,
                    "sigma_mm": c.sigma if done else None,
                    "lcl_mm": lcl if done else None,
                    "ucl_mm": ucl if done else None,
                    "baseline_n": len(c.baseline),
                }
            )
        self._charts = (ids, out)
        return out

    def _with_store(self, read: Callable[[Store], list[dict[str, Any]]]) -> list[dict[str, Any]]:
        """read(store) on a read-only store of the database; nothing while there is none (or
        it has no body tables yet)."""
        if not self.db_path.exists():
            return []
        try:
            store = Store.read_only(self.db_path)
        except (StorageError, sqlite3.Error):
            return []
        try:
            return read(store)
        except (StorageError, sqlite3.Error):
            return []  # a database still being created or migrated: nothing to show yet
        finally:
            store.close()
