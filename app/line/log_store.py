"""The alarms (ISA-18.2's life cycle), the events and the operators' audit in the state
database (schema: app.line.schema): a part of the store (app.line.store.Store inherits it), the
only code that writes their SQL."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from typing import Any

from app.line.states import alarm_event


def dumps(value: Any) -> str:
    """A value as the store keeps JSON: compact."""
    return json.dumps(value, separators=(",", ":"))


class LogRecords:
    """The store's alarms, events and actions (mixed into app.line.store.Store, which supplies
    the connection's transaction and queries)."""

    def _tx(self) -> AbstractContextManager[sqlite3.Connection]:
        raise NotImplementedError

    def _rows(self, sql: str, args: Sequence[Any] = ()) -> list[dict[str, Any]]:
        raise NotImplementedError

    def _insert(self, sql: str, args: Sequence[Any]) -> int:
        raise NotImplementedError

    def raise_alarm(
        self,
        t: float,
        code: str,
        message: str,
        priority: str = "high",
        detail: Mapping[str, Any] | None = None,
    ) -> int:
        """A new alarm, unless one with this code is active already (returns its id). ISA-18.2
        shelves the alarm, not one occurrence: while an earlier one of this code is shelved
        until after `t`, the new one is raised shelved until then, for the same reason.
        `detail`: its structured fields beside the text (app.line.states.alarm_detail)."""
        live = self.active_alarms(code=code)
        if live:
            return int(live[0]["id"])
        shelf = self._rows(
            "SELECT shelved_until, shelve_reason FROM alarms WHERE code = ? AND shelved_until > ?"
            " ORDER BY id DESC LIMIT 1",
            (code, t),
        )
        until, reason = (
            (shelf[0]["shelved_until"], shelf[0]["shelve_reason"]) if shelf else (None, None)
        )
        state = "raised" if until is None else "shelved"
        return self._insert(
            "INSERT INTO alarms (code, priority, message, state, t_raised, shelved_until,"
            " shelve_reason, detail) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (code, priority, message, state, t, until, reason, dumps(detail) if detail else None),
        )

    def update_alarm_message(self, alarm_id: int, message: str) -> None:
        """What an active alarm says, as more is known (e.g. what a flagged step moved)."""
        with self._tx() as db:
            db.execute("UPDATE alarms SET message = ? WHERE id = ?", (message, alarm_id))

    def ack_alarm(self, alarm_id: int, t: float, uid: int | None) -> bool:
        """Acknowledge an alarm nobody has acknowledged yet: a raised one (it becomes acked)
        or one that cleared meanwhile (ISA-18.2's "returned to normal, unacknowledged": it
        stays cleared, acknowledged now). False when there is none such."""
        with self._tx() as db:
            n = db.execute(
                "UPDATE alarms SET t_acked = ?, acked_uid = ?,"
                " state = CASE state WHEN 'raised' THEN 'acked' ELSE state END"
                " WHERE id = ? AND t_acked IS NULL AND state IN ('raised', 'cleared')",
                (t, uid, alarm_id),
            ).rowcount
        return n == 1

    def shelve_alarm(self, alarm_id: int, until_t: float, reason: str) -> bool:
        with self._tx() as db:
            n = db.execute(
                "UPDATE alarms SET state = 'shelved', shelved_until = ?, shelve_reason = ?"
                " WHERE id = ? AND state IN ('raised', 'acked')",
                (until_t, reason, alarm_id),
            ).rowcount
        return n == 1

    def unshelve_expired(self, t: float) -> list[int]:
        """Shelved alarms whose time is up are raised again; their ids (a read when none)."""
        due = self._rows(
            "SELECT id FROM alarms WHERE state = 'shelved' AND shelved_until <= ?", (t,)
        )
        ids = [int(r["id"]) for r in due]
        if ids:
            with self._tx() as db:
                db.executemany(
                    "UPDATE alarms SET state = 'raised' WHERE id = ? AND state = 'shelved'",
                    [(i,) for i in ids],
                )
        return ids

    def clear_alarms(self, t: float, code: str | None = None) -> list[dict[str, Any]]:
        """Clear the active alarms (of one code) at `t`: the one writer of a clearing (the
        service's faults, a maintenance procedure's hand-over), each alarm cleared with its
        `alarm_cleared` event (app.line.states.alarm_event) in the same transaction, so that a
        consumer following the events learns every clearing the rows show. Returns the
        events' data in the order of the alarms (empty: none was active; nothing written)."""
        sql = "SELECT * FROM alarms WHERE state IN ('raised', 'acked', 'shelved')"
        args: tuple[Any, ...] = ()
        if code is not None:
            sql, args = sql + " AND code = ?", (code,)
        sql += " ORDER BY id"
        if not self._rows(sql, args):
            return []
        with self._tx() as db:
            live = [dict(r) for r in db.execute(sql, args).fetchall()]
            db.executemany(
                "UPDATE alarms SET state = 'cleared', t_cleared = ? WHERE id = ?",
                [(t, a["id"]) for a in live],
            )
            events = [alarm_event(a, "cleared") for a in live]
            db.executemany(
                "INSERT INTO events (t, kind, data) VALUES (?, 'alarm_cleared', ?)",
                [(t, dumps(e)) for e in events],
            )
        return events

    def active_alarms(self, code: str | None = None) -> list[dict[str, Any]]:
        sql = "SELECT * FROM alarms WHERE state IN ('raised', 'acked', 'shelved')"
        args: tuple[Any, ...] = ()
        if code is not None:
            sql, args = sql + " AND code = ?", (code,)
        return self._rows(sql + " ORDER BY id", args)

    def alarms(self) -> list[dict[str, Any]]:
        return self._rows("SELECT * FROM alarms ORDER BY id")

    def alarm(self, alarm_id: int) -> dict[str, Any] | None:
        """One alarm by id (None: no such row)."""
        rows = self._rows("SELECT * FROM alarms WHERE id = ?", (alarm_id,))
        return rows[0] if rows else None

    def add_event(self, t: float, kind: str, data: dict[str, Any]) -> int:
        return self._insert(
            "INSERT INTO events (t, kind, data) VALUES (?, ?, ?)", (t, kind, dumps(data))
        )

    def prune_events(self, before_t: float, batch: int = 2000) -> int:
        """Delete events older than `before_t`, `batch` rows a transaction (the service's
        writers wait for one short transaction at most); returns how many."""
        total = 0
        while True:
            with self._tx() as db:
                n = db.execute(
                    "DELETE FROM events WHERE id IN"
                    " (SELECT id FROM events WHERE t < ? ORDER BY id LIMIT ?)",
                    (before_t, batch),
                ).rowcount
            total += int(n)
            if n < batch:
                return total

    def prune_rejected_documents(self, before_t: float) -> int:
        """Drop the full documents of calibrations rejected before `before_t` (their gates,
        figures and reason stay); returns how many."""
        with self._tx() as db:
            return int(
                db.execute(
                    "UPDATE calibrations SET document = NULL"
                    " WHERE status = 'rejected' AND t < ? AND document IS NOT NULL",
                    (before_t,),
                ).rowcount
            )

    def events(self, kind: str | None = None) -> list[dict[str, Any]]:
        where, args = ("WHERE kind = ?", (kind,)) if kind else ("", ())
        rows = self._rows(f"SELECT * FROM events {where} ORDER BY id", args)
        for r in rows:
            r["data"] = json.loads(r["data"])
        return rows

    def add_action(
        self, t: float, uid: int | None, cmd: str, args: dict[str, Any], ok: bool, detail: str
    ) -> int:
        return self._insert(
            "INSERT INTO actions (t, uid, cmd, args, ok, detail) VALUES (?, ?, ?, ?, ?, ?)",
            (t, uid, cmd, dumps(args), int(ok), detail),
        )

    def actions(self) -> list[dict[str, Any]]:
        rows = self._rows("SELECT * FROM actions ORDER BY id")
        for r in rows:
            r["args"] = json.loads(r["args"])
            r["ok"] = bool(r["ok"])
        return rows

    def probe_write(self, n_bytes: int = 256 * 1024) -> None:
        """Commit a row of `n_bytes` and delete it: StorageError unless the storage takes
        writes again (a full disk shows at commit, when the pages reach the WAL)."""
        with self._tx() as db:
            db.execute(
                "INSERT INTO events (t, kind, data) VALUES (0, 'storage_probe', zeroblob(?))",
                (n_bytes,),
            )
        with self._tx() as db:
            db.execute("DELETE FROM events WHERE kind = 'storage_probe'")
