"""The suspect intervals, the clamp windows with their bodies and the maintenance records in
the state database (schema: app.line.schema): a part of the store (app.line.store.Store
inherits it), the only code that writes their SQL."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import Any

from app.line.log_store import dumps

SUSPECTS_SCHEMA = 4  # the version that has suspect_intervals
WINDOWS_SCHEMA = 5  # the version that has windows (the bodies)
MAINTENANCE_SCHEMA = 7  # the version that has maintenance


def suspect_rows(
    db: sqlite3.Connection,
    *,
    since_t: float | None = None,
    last: int | None = None,
    suspect_id: int | None = None,
) -> list[dict[str, Any]]:
    """Suspect intervals in time order, each with `bodies`: the ids of the bodies clamped in
    the windows that opened inside it (from t_start to t_end, an open one up to now), in
    order, each once; in one query. Those still open or ending at or after `since_t` (all
    when None), only the `last` n when given, or only `suspect_id`. None in a database of an
    older rvis (read before a service of this one migrated it); no bodies before the windows
    table. Every reader of suspect intervals comes here (the store, the TUI's history)."""
    version = int(db.execute("PRAGMA user_version").fetchone()[0])
    if version < SUSPECTS_SCHEMA:
        return []
    where: list[str] = []
    args: list[Any] = []
    if since_t is not None:
        where.append("(t_end IS NULL OR t_end >= ?)")
        args.append(since_t)
    if suspect_id is not None:
        where.append("id = ?")
        args.append(suspect_id)
    sql = "SELECT * FROM suspect_intervals"
    sql += f" WHERE {' AND '.join(where)}" if where else ""
    sql += " ORDER BY t_start DESC, id DESC"
    if last is not None:
        sql += " LIMIT ?"
        args.append(last)
    if version < WINDOWS_SCHEMA:
        sql = f"SELECT s.*, NULL AS body FROM ({sql}) AS s ORDER BY s.t_start, s.id"
    else:
        sql = (
            f"SELECT s.*, w.body_id AS body FROM ({sql}) AS s LEFT JOIN windows AS w"
            " ON w.body_id IS NOT NULL AND w.t >= s.t_start"
            " AND (s.t_end IS NULL OR w.t <= s.t_end)"
            " ORDER BY s.t_start, s.id, w.t, w.id"
        )
    out: dict[int, dict[str, Any]] = {}
    cur = db.execute(sql, args)
    names = [d[0] for d in cur.description]
    for r in cur.fetchall():
        row = dict(zip(names, r, strict=True))
        body = row.pop("body")
        interval = out.setdefault(int(row["id"]), {**row, "bodies": []})
        if body is not None and body not in interval["bodies"]:
            interval["bodies"].append(body)
    return list(out.values())


class IntervalRecords:
    """The store's suspect intervals, windows and maintenance records (mixed into
    app.line.store.Store, which supplies the connection's transaction and queries)."""

    def _tx(self) -> AbstractContextManager[sqlite3.Connection]:
        raise NotImplementedError

    def _reading(self) -> AbstractContextManager[sqlite3.Connection]:
        raise NotImplementedError

    def _rows(self, sql: str, args: Sequence[Any] = ()) -> list[dict[str, Any]]:
        raise NotImplementedError

    def _insert(self, sql: str, args: Sequence[Any]) -> int:
        raise NotImplementedError

    def version(self) -> int:
        raise NotImplementedError

    # -- suspect intervals ----------------------------------------------------------------------
    def open_suspect(self, row: dict[str, Any]) -> int:
        """A new open interval: t_start, last_good_id, onset_id, params_version, size_mm,
        group_name, text."""
        return self._insert(
            "INSERT INTO suspect_intervals (t_start, last_good_id, onset_id, params_version,"
            " size_mm, group_name, text) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (
                row["t_start"],
                row.get("last_good_id"),
                row["onset_id"],
                row.get("params_version"),
                row.get("size_mm"),
                row.get("group_name"),
                row.get("text", ""),
            ),
        )

    _SUSPECT_FIELDS = frozenset(
        {
            "t_start",
            "last_good_id",
            "size_mm",
            "group_name",
            "text",
            "t_end",
            "end_reason",
            "end_version",
            "calibration_id",
            "onset_id",
            "params_version",
            "reevaluated",
            "decisions_changed",
            "not_reevaluated",
        }
    )

    def update_suspect(self, suspect_id: int, **fields: Any) -> None:
        """Set some of: t_start and last_good_id (the step located more precisely), size_mm,
        group_name, text, t_end, end_reason, end_version, calibration_id (closing it: t_end
        and end_reason); reevaluated, decisions_changed and not_reevaluated (its bodies
        computed again with the correction)."""
        unknown = set(fields) - self._SUSPECT_FIELDS
        if unknown:
            raise ValueError(f"unknown suspect interval fields {sorted(unknown)}")
        sets = ", ".join(f"{k} = ?" for k in fields)
        with self._tx() as db:
            db.execute(
                f"UPDATE suspect_intervals SET {sets} WHERE id = ?", (*fields.values(), suspect_id)
            )

    def suspect(self, suspect_id: int) -> dict[str, Any] | None:
        """One interval with its bodies (`suspect_rows`), None: no such one."""
        with self._reading() as db:
            rows = suspect_rows(db, suspect_id=suspect_id)
        return rows[0] if rows else None

    def suspects(
        self, since_t: float | None = None, last: int | None = None
    ) -> list[dict[str, Any]]:
        """Intervals in time order with their bodies (`suspect_rows`): those still open or
        ending at or after `since_t` (all when None); only the `last` n when given."""
        with self._reading() as db:
            return suspect_rows(db, since_t=since_t, last=last)

    # -- clamp windows and their bodies -----------------------------------------------------------
    def add_window(self, t: float, body_id: int | str | None) -> int:
        """A clamp window that opened at `t` with the body the PLC clamped in it (None: none)."""
        return self._insert("INSERT INTO windows (t, body_id) VALUES (?, ?)", (t, body_id))

    def state_window_u95(self, u95_mm: float | None) -> None:
        """The U95 [mm] stated for the bodies of the last window recorded (app.line.accuracy)."""
        with self._tx() as db:
            db.execute(
                "UPDATE windows SET u95_mm = ? WHERE id = (SELECT MAX(id) FROM windows)",
                (u95_mm,),
            )

    def last_statement(self) -> dict[str, Any] | None:
        """The last window a U95 was stated for: {t, u95_mm} (None: none yet)."""
        if self.version() <= WINDOWS_SCHEMA:  # u95_mm came with the next one
            return None
        rows = self._rows(
            "SELECT t, u95_mm FROM windows WHERE u95_mm IS NOT NULL ORDER BY id DESC LIMIT 1"
        )
        return rows[0] if rows else None

    def vouched_since(self, t_from: float, limit_mm: float) -> float | None:
        """The open time of the first window at or after `t_from` from which on every window's
        stated U95 is within `limit_mm` (`t_from` itself when all are; None when the last
        one's is not, or no window was recorded)."""
        with self._reading() as db:
            last = db.execute("SELECT MAX(t) FROM windows").fetchone()[0]
            worse = db.execute(
                "SELECT MAX(t) FROM windows WHERE t >= ? AND (u95_mm IS NULL OR u95_mm > ?)",
                (t_from, limit_mm),
            ).fetchone()[0]
            if last is None or worse == last:
                return None
            if worse is None:
                return t_from
            return float(
                db.execute("SELECT MIN(t) FROM windows WHERE t > ?", (worse,)).fetchone()[0]
            )

    def windows_of(self, body_id: Any) -> list[dict[str, Any]]:
        """The clamp windows the body `body_id` was clamped in (a number or its text), in time
        order, each with the U95 stated for its bodies."""
        if self.version() < WINDOWS_SCHEMA:
            return []
        return self._rows(
            "SELECT * FROM windows WHERE CAST(body_id AS TEXT) = CAST(? AS TEXT) ORDER BY t, id",
            (body_id,),
        )

    def windows(self) -> list[dict[str, Any]]:
        """Every clamp window recorded, in time order (t, body_id)."""
        if self.version() < WINDOWS_SCHEMA:
            return []
        return self._rows("SELECT * FROM windows ORDER BY t, id")

    # -- maintenance procedures (app/maintain/) ---------------------------------------------------
    def start_maintenance(self, row: dict[str, Any]) -> int:
        """A procedure begins: t_start, event, axis, who, folder, version_before, before."""
        return self._insert(
            "INSERT INTO maintenance (t_start, event, axis, who, folder, status, version_before,"
            " before) VALUES (?, ?, ?, ?, ?, 'running', ?, ?)",
            (
                row["t_start"],
                row["event"],
                row.get("axis"),
                row["who"],
                row["folder"],
                row.get("version_before"),
                dumps(row.get("before", {})),
            ),
        )

    def finish_maintenance(
        self, maintenance_id: int, t_end: float, version_after: int, after: dict[str, Any]
    ) -> None:
        """The procedure handed the cell back with version_after and its figures."""
        with self._tx() as db:
            db.execute(
                "UPDATE maintenance SET t_end = ?, status = 'done', version_after = ?, after = ?"
                " WHERE id = ?",
                (t_end, version_after, dumps(after), maintenance_id),
            )

    def abandon_maintenance(self, maintenance_id: int, t_end: float, reason: str) -> None:
        """A running procedure given up (begun again): no version handed over."""
        with self._tx() as db:
            db.execute(
                "UPDATE maintenance SET t_end = ?, status = 'abandoned', after = ?"
                " WHERE id = ? AND status = 'running'",
                (t_end, dumps({"reason": reason}), maintenance_id),
            )

    def maintenance(self, last: int | None = None) -> list[dict[str, Any]]:
        """The maintenance records in time order (the `last` n when given); none in a
        database of an older rvis."""
        if self.version() < MAINTENANCE_SCHEMA:
            return []
        sql = "SELECT * FROM maintenance ORDER BY id DESC"
        rows = self._rows(sql + (" LIMIT ?" if last is not None else ""), (last,) if last else ())
        for r in rows:
            r["before"], r["after"] = json.loads(r["before"]), json.loads(r["after"])
        return rows[::-1]
