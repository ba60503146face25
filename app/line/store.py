"""SQLite persistence of the service: the only code in rvis that writes SQL.

One file `state_dir/rvis.db` in WAL mode. Every write is one `BEGIN IMMEDIATE` transaction with
`synchronous=FULL`, so a row is on disk before the caller acknowledges it to anyone (the PLC's
`done` comes after `add_measurement` returns). The schema version is `PRAGMA user_version`;
`MIGRATIONS[k]` brings version k to k + 1, each in its own transaction. Readers such as
`rvis status` or the TUI open the file read-only (`Store.read_only`).

Tables: measurements (ok and rejected, with their quality), calibrations (gates, status
pending/applied/rejected), applied (parameter versions in force, in order), alarms (ISA-18.2
life cycle: raised, acked, cleared, shelved with reason and expiry), events, actions (operator
audit with the peer's uid), schedule (the position to resume from), suspect_intervals (from the last
trustworthy measurement before a step to the apply of its correction: when the calibration in
force was wrong, with its estimated size), windows (the clamp windows the PLC opened, with the
body clamped in each when `[line] plc_body_id` reads it: a suspect interval's bodies are those
of the windows inside it), service_state (one JSON
document: what the service's decisions depend on beyond the rows themselves, written in the
same transaction as the measurement or the apply that changed it, so a restarted service
resumes exactly where it stopped).

Failures are typed: a database that is not one, or fails its quick check at open, is
`DatabaseDamaged` (refused, never recreated or modified); any other SQLite or I/O failure
(disk full, I/O error, read-only file system) is `StorageError`, with the transaction rolled
back, so nothing that was not committed is ever acknowledged.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from app.errors import InputError, RvisError
from app.line.body_store import BodyRecords
from app.line.schema import MIGRATIONS


class StorageError(RvisError):
    """The state storage failed (disk full, I/O error, read-only): nothing was committed."""


class DatabaseDamaged(InputError):
    """The database is not an SQLite database or fails its integrity check (exit code 2)."""


SCHEMA_VERSION = len(MIGRATIONS)
SUSPECTS_SCHEMA = 4  # the version that has suspect_intervals
WINDOWS_SCHEMA = 5  # the version that has windows (the bodies)
MAINTENANCE_SCHEMA = 7  # the version that has maintenance
# SQLite primary result codes: BUSY, LOCKED, NOMEM, READONLY, IOERR, FULL, CANTOPEN, PROTOCOL
_STORAGE_CODES = frozenset({5, 6, 7, 8, 10, 13, 14, 15})
_DAMAGED_CODES = frozenset({11, 26})  # CORRUPT, NOTADB
_DAMAGED = (
    "the state database is damaged; rvis does not modify it: restore a copy made with"
    " `rvis state backup`, or move it aside to start a new history"
)
ACTIVE_ALARM_STATES = ("raised", "acked", "shelved")


def _calibration_row(r: dict[str, Any]) -> dict[str, Any]:
    r["gates"] = json.loads(r["gates"])
    r["document"] = None if r["document"] is None else json.loads(r["document"])
    return r


def _measurement_row(r: dict[str, Any]) -> dict[str, Any]:
    r["q_deg"] = json.loads(r["q_deg"])
    r["c_sensor_mm"] = None if r["c_sensor_mm"] is None else json.loads(r["c_sensor_mm"])
    r["quality"] = json.loads(r["quality"])
    return r


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


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


class Store(BodyRecords):
    """`Store(path)` opens (creating and migrating) the database; thread-safe; close() it."""

    def __init__(self, path: str | Path, *, read_only: bool = False) -> None:
        self.path = Path(path)
        self._lock = threading.RLock()
        self._depth = 0  # nesting of _tx: only the outermost one begins and commits
        try:
            with self._typed_errors():
                self._connect(read_only)
        except OSError as exc:
            raise StorageError(f"{self.path}: {exc.strerror or exc}") from exc
        self._db.row_factory = sqlite3.Row

    def _connect(self, read_only: bool) -> None:
        if read_only:
            uri = f"file:{self.path.resolve()}?mode=ro"
            self._db = sqlite3.connect(uri, uri=True, check_same_thread=False)
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
            self._open_for_writing()

    def _open_for_writing(self) -> None:
        try:
            self._db.execute("PRAGMA journal_mode=WAL")
            check = self._db.execute("PRAGMA quick_check").fetchone()[0]
        except sqlite3.DatabaseError:
            self._db.close()
            raise
        if check != "ok":
            self._db.close()
            raise DatabaseDamaged(f"{_DAMAGED} (quick_check: {check})", file=self.path)
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA busy_timeout=5000")
        self.migrate()

    @contextmanager
    def _typed_errors(self) -> Iterator[None]:
        """SQLite failures inside raised as their typed error (`_error`)."""
        try:
            yield
        except sqlite3.DatabaseError as exc:
            error = self._error(exc)
            if error is exc:
                raise
            raise error from exc

    def _error(self, exc: sqlite3.DatabaseError) -> BaseException:
        """The typed error of an SQLite failure by its result code: a storage failure (full,
        I/O, read-only, locked, cannot open), a damaged file, or the error itself (a syntax
        or constraint error is a bug, not a fault of the storage)."""
        code = getattr(exc, "sqlite_errorcode", -1) & 0xFF
        if code in _STORAGE_CODES:
            return StorageError(f"{self.path}: {exc}")
        if code in _DAMAGED_CODES:
            return DatabaseDamaged(f"{_DAMAGED} ({exc})", file=self.path)
        return exc

    @classmethod
    def read_only(cls, path: str | Path) -> Store:
        return cls(path, read_only=True)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- transactions and schema ----------------------------------------------------------
    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One writer transaction: BEGIN IMMEDIATE ... COMMIT (ROLLBACK on any error); nested
        inside `batch()` it joins the outer transaction. SQLite failures -> StorageError."""
        with self._lock:
            outer = self._depth == 0
            try:
                if outer:
                    self._db.execute("BEGIN IMMEDIATE")
                self._depth += 1
                try:
                    yield self._db
                finally:
                    self._depth -= 1
                if outer:
                    self._db.execute("COMMIT")
            except BaseException as exc:
                if outer and self._db.in_transaction:
                    with suppress(sqlite3.Error):
                        self._db.execute("ROLLBACK")
                error = self._error(exc) if isinstance(exc, sqlite3.DatabaseError) else exc
                if error is exc:
                    raise
                raise error from exc

    @contextmanager
    def batch(self) -> Iterator[None]:
        """Every write inside is one transaction (all or nothing), e.g. a measurement with the
        decision state it changed."""
        with self._tx():
            yield

    def version(self) -> int:
        with self._lock:
            return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def migrate(self, migrations: Sequence[Sequence[str]] = MIGRATIONS) -> int:
        """Apply the missing migrations, each atomically with its version bump."""
        for k in range(self.version(), len(migrations)):
            with self._tx() as db:
                for statement in migrations[k]:
                    db.execute(statement)
                db.execute(f"PRAGMA user_version = {k + 1}")
        return self.version()

    def integrity_ok(self) -> bool:
        return not self.integrity_problems()

    def integrity_problems(self, limit: int = 10) -> list[str]:
        """`PRAGMA integrity_check`'s findings (empty: the file is sound)."""
        rows = self._rows(f"PRAGMA integrity_check({int(limit)})")
        found = [str(next(iter(r.values()))) for r in rows]
        return [] if found == ["ok"] else found

    def table_bytes(self) -> dict[str, int]:
        """Bytes of every table with its indexes (SQLite's dbstat), free pages as `(free)`."""
        out: dict[str, int] = {}
        owner = {
            r["name"]: r["tbl_name"] for r in self._rows("SELECT name, tbl_name FROM sqlite_schema")
        }
        for r in self._rows("SELECT name, SUM(pgsize) AS n FROM dbstat GROUP BY name"):
            table = owner.get(r["name"], r["name"])
            out[table] = out.get(table, 0) + int(r["n"])
        page = int(self._rows("PRAGMA page_size")[0]["page_size"])
        out["(free)"] = page * int(self._rows("PRAGMA freelist_count")[0]["freelist_count"])
        return out

    def backup(self, dest: str | Path) -> None:
        """A consistent copy of the database at `dest` while the service keeps writing: SQLite's
        online backup in one step, i.e. one read transaction, which in WAL mode never blocks
        the writer (copied in steps, a write by another process would restart it). `dest`
        must not exist."""
        dest = Path(dest)
        if dest.exists():
            raise InputError("exists already: rvis does not overwrite a database", file=dest)
        with self._typed_errors():
            target = sqlite3.connect(dest)
            try:
                with self._lock:  # the connection is shared with the service's thread
                    self._db.backup(target)
                target.execute("PRAGMA journal_mode=DELETE")  # one self-contained file
            finally:
                target.close()

    def _rows(self, sql: str, args: Sequence[Any] = ()) -> list[dict[str, Any]]:
        with self._lock, self._typed_errors():
            return [dict(r) for r in self._db.execute(sql, tuple(args)).fetchall()]

    def _insert(self, sql: str, args: Sequence[Any]) -> int:
        with self._tx() as db:
            row_id = db.execute(sql, tuple(args)).lastrowid
        assert row_id is not None
        return int(row_id)

    # -- measurements -----------------------------------------------------------------------
    def add_measurement(self, row: dict[str, Any]) -> int:
        """Store one measurement and its new schedule position in one transaction; returns its
        id once committed to disk. `row`: t, window, slot, target, q_deg, c_sensor_mm (None if
        rejected), status, reason, quality, params_version, residual_mm, next_position and
        optionally temp_c."""
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO measurements (t, window, slot, target, q_deg, c_sensor_mm, status,"
                " reason, quality, params_version, residual_mm, temp_c)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    row["t"],
                    row["window"],
                    row["slot"],
                    row["target"],
                    _dumps(list(row["q_deg"])),
                    None if row["c_sensor_mm"] is None else _dumps(list(row["c_sensor_mm"])),
                    row["status"],
                    row.get("reason", ""),
                    _dumps(row.get("quality", {})),
                    row.get("params_version"),
                    row.get("residual_mm"),
                    row.get("temp_c"),
                ),
            )
            db.execute(
                "UPDATE schedule SET position = ?, window = ? WHERE id = 1",
                (row["next_position"], row["window"]),
            )
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def measurements(
        self,
        *,
        status: str = "ok",
        since_id: int = 0,
        last: int | None = None,
        before_id: int | None = None,
    ) -> list[dict[str, Any]]:
        """Rows of `status` after `since_id` (and before `before_id`) in id order (only the
        `last` n when given)."""
        sql = "SELECT * FROM measurements WHERE status = ? AND id > ?"
        args: tuple[Any, ...] = (status, since_id)
        if before_id is not None:
            sql, args = sql + " AND id < ?", (*args, before_id)
        sql += " ORDER BY id DESC"
        if last is not None:
            sql, args = sql + " LIMIT ?", (*args, last)
        return [_measurement_row(r) for r in self._rows(sql, args)[::-1]]

    def rejected_in_a_row(
        self, n: int, window_rows: int = 2000, since_id: int = 0
    ) -> dict[int, int]:
        """slot -> how many times it was rejected since its last good measurement, for the slots
        rejected at least n times so, among the last `window_rows` measurements after
        `since_id` (newest first, each slot counted until its first good one: bounded,
        whatever the table's size)."""
        rows = self._rows(
            "SELECT slot, status FROM measurements WHERE id > ? ORDER BY id DESC LIMIT ?",
            (since_id, window_rows),
        )
        streak: dict[int, int] = {}
        done: set[int] = set()
        for r in rows:
            slot = int(r["slot"])
            if slot in done:
                continue
            if r["status"] == "rejected":
                streak[slot] = streak.get(slot, 0) + 1
            else:
                done.add(slot)
        return {slot: k for slot, k in streak.items() if k >= n}

    def measurements_by_id(self, ids: Sequence[int]) -> list[dict[str, Any]]:
        """The rows of these ids in id order (any status)."""
        marks = ",".join("?" * len(ids))
        rows = self._rows(f"SELECT * FROM measurements WHERE id IN ({marks}) ORDER BY id", ids)
        return [_measurement_row(r) for r in rows]

    def last_measurement_id(self) -> int:
        return int(self._rows("SELECT COALESCE(MAX(id), 0) AS n FROM measurements")[0]["n"])

    def last_time(self) -> float | None:
        """The latest time [s, the service's clock] the database records (None: empty)."""
        r = self._rows(
            "SELECT MAX(t) AS t FROM (SELECT MAX(t) AS t FROM events"
            " UNION ALL SELECT MAX(t) FROM measurements UNION ALL SELECT MAX(t) FROM applied)"
        )
        t = r[0]["t"] if r else None
        return None if t is None else float(t)

    def counts(self) -> dict[str, int]:
        out = {"ok": 0, "rejected": 0}
        for r in self._rows("SELECT status, COUNT(*) AS n FROM measurements GROUP BY status"):
            out[r["status"]] = int(r["n"])
        return out

    def schedule_position(self) -> tuple[int, int]:
        """(next schedule position, last window number)."""
        r = self._rows("SELECT position, window FROM schedule WHERE id = 1")[0]
        return int(r["position"]), int(r["window"])

    def set_window(self, window: int) -> None:
        with self._tx() as db:
            db.execute("UPDATE schedule SET window = ? WHERE id = 1", (window,))

    # -- calibrations and applied versions --------------------------------------------------
    def add_calibration(self, row: dict[str, Any]) -> int:
        return self._insert(
            "INSERT INTO calibrations (t, status, n_measurements, first_id, last_id, rms_mm,"
            " holdout_rms_mm, current_holdout_rms_mm, gates, reason, document)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                row["t"],
                row["status"],
                row["n_measurements"],
                row.get("first_id"),
                row.get("last_id"),
                row.get("rms_mm"),
                row.get("holdout_rms_mm"),
                row.get("current_holdout_rms_mm"),
                _dumps(row.get("gates", [])),
                row["reason"],
                None if row.get("document") is None else _dumps(row["document"]),
            ),
        )

    def decide_calibration(
        self, cal_id: int, status: str, t: float, uid: int | None, version: int | None = None
    ) -> None:
        with self._tx() as db:
            db.execute(
                "UPDATE calibrations SET status = ?, decided_t = ?, decided_uid = ?, version = ?"
                " WHERE id = ?",
                (status, t, uid, version, cal_id),
            )

    def calibrations(self, status: str | None = None) -> list[dict[str, Any]]:
        where, args = ("WHERE status = ?", (status,)) if status else ("", ())
        rows = self._rows(f"SELECT * FROM calibrations {where} ORDER BY id", args)
        return [_calibration_row(r) for r in rows]

    def calibration(self, cal_id: int | None) -> dict[str, Any] | None:
        """One calibration by id (None: no such row), without reading the others."""
        rows = self._rows("SELECT * FROM calibrations WHERE id = ?", (cal_id,))
        return _calibration_row(rows[0]) if rows else None

    def pending_calibration(self) -> int | None:
        """The newest calibration waiting for a decision (None: none)."""
        rows = self._rows("SELECT MAX(id) AS id FROM calibrations WHERE status = 'pending'")
        return None if rows[0]["id"] is None else int(rows[0]["id"])

    def add_applied(
        self, t: float, version: int, calibration_id: int | None, source: str, uid: int | None
    ) -> int:
        return self._insert(
            "INSERT INTO applied (t, version, calibration_id, source, uid) VALUES (?, ?, ?, ?, ?)",
            (t, version, calibration_id, source, uid),
        )

    def applied(self) -> list[dict[str, Any]]:
        return self._rows("SELECT * FROM applied ORDER BY id")

    # -- alarms, events, audit ----------------------------------------------------------------
    def raise_alarm(self, t: float, code: str, message: str, priority: str = "high") -> int:
        """A new alarm, unless one with this code is active already (returns its id). ISA-18.2
        shelves the alarm, not one occurrence: while an earlier one of this code is shelved
        until after `t`, the new one is raised shelved until then, for the same reason."""
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
        return self._insert(
            "INSERT INTO alarms (code, priority, message, state, t_raised, shelved_until,"
            " shelve_reason) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (code, priority, message, "raised" if until is None else "shelved", t, until, reason),
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

    def clear_alarms(self, t: float, code: str | None = None) -> int:
        """Clear the active alarms (of one code); returns how many."""
        sql = "UPDATE alarms SET state = 'cleared', t_cleared = ? WHERE state != 'cleared'"
        args: tuple[Any, ...] = (t,)
        if code is not None:
            sql, args = sql + " AND code = ?", (t, code)
        with self._tx() as db:
            return int(db.execute(sql, args).rowcount)

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
            "INSERT INTO events (t, kind, data) VALUES (?, ?, ?)", (t, kind, _dumps(data))
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
            (t, uid, cmd, _dumps(args), int(ok), detail),
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
        with self._lock, self._typed_errors():
            rows = suspect_rows(self._db, suspect_id=suspect_id)
        return rows[0] if rows else None

    def suspects(
        self, since_t: float | None = None, last: int | None = None
    ) -> list[dict[str, Any]]:
        """Intervals in time order with their bodies (`suspect_rows`): those still open or
        ending at or after `since_t` (all when None); only the `last` n when given."""
        with self._lock, self._typed_errors():
            return suspect_rows(self._db, since_t=since_t, last=last)

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
        with self._lock, self._typed_errors():
            last = self._db.execute("SELECT MAX(t) FROM windows").fetchone()[0]
            worse = self._db.execute(
                "SELECT MAX(t) FROM windows WHERE t >= ? AND (u95_mm IS NULL OR u95_mm > ?)",
                (t_from, limit_mm),
            ).fetchone()[0]
            if last is None or worse == last:
                return None
            if worse is None:
                return t_from
            return float(
                self._db.execute("SELECT MIN(t) FROM windows WHERE t > ?", (worse,)).fetchone()[0]
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
                _dumps(row.get("before", {})),
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
                (t_end, version_after, _dumps(after), maintenance_id),
            )

    def abandon_maintenance(self, maintenance_id: int, t_end: float, reason: str) -> None:
        """A running procedure given up (begun again): no version handed over."""
        with self._tx() as db:
            db.execute(
                "UPDATE maintenance SET t_end = ?, status = 'abandoned', after = ?"
                " WHERE id = ? AND status = 'running'",
                (t_end, _dumps({"reason": reason}), maintenance_id),
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

    # -- the service's decision state ---------------------------------------------------------
    def save_state(self, t: float, doc: dict[str, Any]) -> None:
        with self._tx() as db:
            db.execute(
                "INSERT INTO service_state (id, t, doc) VALUES (1, ?, ?)"
                " ON CONFLICT (id) DO UPDATE SET t = excluded.t, doc = excluded.doc",
                (t, _dumps(doc)),
            )

    def load_state(self) -> dict[str, Any] | None:
        rows = self._rows("SELECT doc FROM service_state WHERE id = 1")
        return None if not rows else dict(json.loads(rows[0]["doc"]))
