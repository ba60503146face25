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
from app.line.interval_store import IntervalRecords
from app.line.log_store import LogRecords, dumps
from app.line.schema import MIGRATIONS


class StorageError(RvisError):
    """The state storage failed (disk full, I/O error, read-only): nothing was committed."""


class DatabaseDamaged(InputError):
    """The database is not an SQLite database or fails its integrity check (exit code 2)."""


SCHEMA_VERSION = len(MIGRATIONS)
# SQLite primary result codes: BUSY, LOCKED, NOMEM, READONLY, IOERR, FULL, CANTOPEN, PROTOCOL
_STORAGE_CODES = frozenset({5, 6, 7, 8, 10, 13, 14, 15})
_DAMAGED_CODES = frozenset({11, 26})  # CORRUPT, NOTADB
_DAMAGED = (
    "the state database is damaged; rvis does not modify it: restore a copy made with"
    " `rvis state backup`, or move it aside to start a new history"
)


def _calibration_row(r: dict[str, Any]) -> dict[str, Any]:
    r["gates"] = json.loads(r["gates"])
    r["document"] = None if r["document"] is None else json.loads(r["document"])
    return r


def _measurement_row(r: dict[str, Any]) -> dict[str, Any]:
    r["q_deg"] = json.loads(r["q_deg"])
    r["c_sensor_mm"] = None if r["c_sensor_mm"] is None else json.loads(r["c_sensor_mm"])
    r["quality"] = json.loads(r["quality"])
    return r


class Store(BodyRecords, LogRecords, IntervalRecords):
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

    @contextmanager
    def _reading(self) -> Iterator[sqlite3.Connection]:
        """The connection for a read of several statements (under the lock, errors typed)."""
        with self._lock, self._typed_errors():
            yield self._db

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
                    dumps(list(row["q_deg"])),
                    None if row["c_sensor_mm"] is None else dumps(list(row["c_sensor_mm"])),
                    row["status"],
                    row.get("reason", ""),
                    dumps(row.get("quality", {})),
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

    def measurements_of_version(self, version: int) -> list[dict[str, Any]]:
        """The good rows measured with parameters `version` since it was last put in force, in
        id order: the newest run of rows when the newest row is the version's (read back to the
        first row of another version); none when the newest row is another version's (the
        version put in force again, by a rollback: its old run is another period of the cell's,
        and the estimator that replayed it would take the cell then for the cell now)."""
        newest = self._rows("SELECT id, params_version FROM measurements ORDER BY id DESC LIMIT 1")
        if not newest or newest[0]["params_version"] != version:
            return []
        other = self._rows(
            "SELECT MAX(id) AS id FROM measurements WHERE params_version IS NOT ?", (version,)
        )
        since = other[0]["id"]
        return self.measurements(since_id=int(since or 0), before_id=int(newest[0]["id"]) + 1)

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
                dumps(row.get("gates", [])),
                row["reason"],
                None if row.get("document") is None else dumps(row["document"]),
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

    # -- the service's decision state ---------------------------------------------------------
    def save_state(self, t: float, doc: dict[str, Any]) -> None:
        with self._tx() as db:
            db.execute(
                "INSERT INTO service_state (id, t, doc) VALUES (1, ?, ?)"
                " ON CONFLICT (id) DO UPDATE SET t = excluded.t, doc = excluded.doc",
                (t, dumps(doc)),
            )

    def load_state(self) -> dict[str, Any] | None:
        rows = self._rows("SELECT doc FROM service_state WHERE id = 1")
        return None if not rows else dict(json.loads(rows[0]["doc"]))
