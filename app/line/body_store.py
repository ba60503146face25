"""The bodies in the state database (schema: app.line.schema, migration 9): a part of the store
(app.line.store.Store inherits it), the only code that writes their SQL.

A body is stored in one transaction with its raw data and its first evaluation (0): the values
as measured. An evaluation computed again later (a step found after the body was measured and
corrected) is added beside the earlier ones with its reason; a body's newest evaluation is the
one its results show, the earlier ones stay.

Rows are plain dicts of JSON-ready values; the raw points are little-endian float32 (x, y, z)
rows, as numpy reads them back (`points_of`).
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy loads when a body's points are read or written, not with the store
    import numpy as np
    from numpy.typing import NDArray

    F64 = NDArray[np.float64]
VALUE_FIELDS = (
    "feature", "characteristic", "kind", "nominal_mm", "lower_mm", "upper_mm", "measured_mm",
    "u95_mm", "decision", "reason",
)  # fmt: skip
EVALUATION_FIELDS = (
    "t", "params_version", "statement_u95_mm", "reason", "suspect_id", "ok", "n_nok",
    "n_undecided", "n_not_measured", "decisions_changed",
)  # fmt: skip


#: a body id as its file's name spells it (app.line.body_export.file_name: str() of the id)
_NAME = "COALESCE(CAST(body_id AS TEXT), 'None')"


def _joints(text: str) -> F64:
    import numpy as np

    out: F64 = np.array(json.loads(text), dtype=float)
    return out


def points_blob(points: F64 | None) -> bytes | None:
    import numpy as np

    return None if points is None else np.asarray(points, dtype="<f4").reshape(-1, 3).tobytes()


def points_of(blob: bytes | None) -> F64 | None:
    import numpy as np

    if blob is None:
        return None
    out: F64 = np.frombuffer(blob, dtype="<f4").reshape(-1, 3).astype(np.float64)
    return out


class BodyRecords:
    """The store's body tables (mixed into app.line.store.Store, which supplies the
    connection's transaction and queries)."""

    def _tx(self) -> AbstractContextManager[sqlite3.Connection]:
        raise NotImplementedError

    def _rows(self, sql: str, args: Sequence[Any] = ()) -> list[dict[str, Any]]:
        raise NotImplementedError

    def add_body(
        self,
        body: dict[str, Any],
        evaluation: dict[str, Any],
        values: Sequence[dict[str, Any]],
        raw: Sequence[dict[str, Any]],
    ) -> int:
        """Store a measured body (t, body_id, part, window, temp_c), its first evaluation
        (EVALUATION_FIELDS), its values (VALUE_FIELDS) and raw data per feature (feature,
        q_deg, temp_c, sheet, edges (n, 3) or None, refused) in one transaction; its row id."""
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO bodies (t, body_id, part, window, temp_c, evaluation)"
                " VALUES (?, ?, ?, ?, ?, 0)",
                (
                    body["t"],
                    body.get("body_id"),
                    body["part"],
                    body.get("window"),
                    body.get("temp_c"),
                ),
            )
            row = int(cur.lastrowid or 0)
            self._write_evaluation(db, row, 0, evaluation, values)
            db.executemany(
                "INSERT INTO body_raw (body, feature, stop, q_deg, temp_c, sheet, edges, refused)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (
                        row, r["feature"], int(r.get("stop", 0)),
                        json.dumps([float(a) for a in r["q_deg"]]),
                        r.get("temp_c"), points_blob(r.get("sheet")), points_blob(r.get("edges")),
                        r.get("refused", ""),
                    )
                    for r in raw
                ],
            )  # fmt: skip
        return row

    def add_evaluation(
        self, body_row: int, evaluation: dict[str, Any], values: Sequence[dict[str, Any]]
    ) -> int:
        """A body's values computed again: the next evaluation number, beside the others."""
        with self._tx() as db:
            n = int(
                db.execute("SELECT evaluation FROM bodies WHERE id = ?", (body_row,)).fetchone()[0]
            )
            self._write_evaluation(db, body_row, n + 1, evaluation, values)
            db.execute("UPDATE bodies SET evaluation = ? WHERE id = ?", (n + 1, body_row))
        return n + 1

    @staticmethod
    def _write_evaluation(
        db: sqlite3.Connection,
        row: int,
        n: int,
        evaluation: dict[str, Any],
        values: Sequence[dict[str, Any]],
    ) -> None:
        db.execute(
            f"INSERT INTO body_evaluations (body, evaluation, {', '.join(EVALUATION_FIELDS)})"
            f" VALUES (?, ?, {', '.join('?' * len(EVALUATION_FIELDS))})",
            (row, n, *(evaluation.get(k) for k in EVALUATION_FIELDS)),
        )
        db.executemany(
            f"INSERT INTO body_values (body, evaluation, {', '.join(VALUE_FIELDS)})"
            f" VALUES (?, ?, {', '.join('?' * len(VALUE_FIELDS))})",
            [(row, n, *(v.get(k) for k in VALUE_FIELDS)) for v in values],
        )

    def bodies(
        self,
        since_t: float | None = None,
        until_t: float | None = None,
        body_id: Any = None,
        *,
        row: int | None = None,
        evaluation: int | None = None,
        first: int | None = None,
        last: int | None = None,
    ) -> list[dict[str, Any]]:
        """Bodies (oldest first) with their newest evaluation's summary (or `evaluation`'s),
        measured within [since_t, until_t] and/or with the body id given (or the body `row`);
        only the `first` or the `last` n of them when given."""
        where: list[str] = [
            "e.evaluation = b.evaluation" if evaluation is None else "e.evaluation = ?"
        ]
        args: list[Any] = [] if evaluation is None else [evaluation]
        if row is not None:
            where.append("b.id = ?")
            args.append(row)
        if since_t is not None:
            where.append("b.t >= ?")
            args.append(since_t)
        if until_t is not None:
            where.append("b.t <= ?")
            args.append(until_t)
        if body_id is not None:
            where.append("CAST(b.body_id AS TEXT) = CAST(? AS TEXT)")
            args.append(body_id)
        order, limit = ("DESC", last) if last is not None else ("", first)
        rows = self._rows(
            "SELECT b.id, b.t, b.body_id, b.part, b.window, b.temp_c, e.evaluation,"
            " e.params_version, e.statement_u95_mm, e.reason, e.ok, e.n_nok, e.n_undecided,"
            " e.n_not_measured, e.decisions_changed, e.suspect_id"
            " FROM bodies b JOIN body_evaluations e ON e.body = b.id"
            f" WHERE {' AND '.join(where)} ORDER BY b.id {order}"
            + ("" if limit is None else " LIMIT ?"),
            args if limit is None else [*args, limit],
        )
        return rows[::-1] if last is not None else rows

    def body_values(self, body_row: int, evaluation: int | None = None) -> list[dict[str, Any]]:
        """A body's values of one evaluation (default: its newest), in plan order."""
        if evaluation is None:
            rows = self._rows("SELECT evaluation FROM bodies WHERE id = ?", (body_row,))
            if not rows:
                return []
            evaluation = int(rows[0]["evaluation"])
        return self._rows(
            f"SELECT {', '.join(VALUE_FIELDS)} FROM body_values"
            " WHERE body = ? AND evaluation = ? ORDER BY rowid",
            (body_row, evaluation),
        )

    def body_evaluations(self, body_row: int) -> list[dict[str, Any]]:
        return self._rows(
            "SELECT * FROM body_evaluations WHERE body = ? ORDER BY evaluation", (body_row,)
        )

    def unexported(self, limit: int = 100) -> list[tuple[int, int]]:
        """(body row, evaluation) of the evaluations whose file is not written yet, oldest
        first."""
        rows = self._rows(
            "SELECT body, evaluation FROM body_evaluations WHERE exported_t IS NULL"
            " ORDER BY body, evaluation LIMIT ?",
            (limit,),
        )
        return [(int(r["body"]), int(r["evaluation"])) for r in rows]

    def mark_exported(self, body_row: int, evaluation: int, t: float) -> None:
        with self._tx() as db:
            db.execute(
                "UPDATE body_evaluations SET exported_t = ? WHERE body = ? AND evaluation = ?",
                (t, body_row, evaluation),
            )

    def expired_bodies(
        self, before_t: float, *, keep_unexported: bool, limit: int = 1000
    ) -> list[dict[str, Any]]:
        """The bodies measured before `before_t` that retention may delete, oldest first (at
        most `limit`): none measured inside a suspect interval still open (at or after its
        start), and with `keep_unexported` none with an evaluation whose file waits to be
        written (app.line.body_export). Each: id, body_id, part and `files`, the evaluations
        whose files were written and are still theirs (no later body of the same part and id,
        measured again, has written a file of that name since)."""
        pending = (
            " AND NOT EXISTS (SELECT 1 FROM body_evaluations e"
            " WHERE e.body = b.id AND e.exported_t IS NULL)"
            if keep_unexported
            else ""
        )
        rows = self._rows(
            "SELECT b.id, b.body_id, b.part, (SELECT GROUP_CONCAT(e.evaluation)"
            " FROM body_evaluations e WHERE e.body = b.id AND e.exported_t IS NOT NULL)"
            " AS exported FROM bodies b WHERE b.t < ? AND NOT EXISTS (SELECT 1 FROM"
            " suspect_intervals s WHERE s.t_end IS NULL AND b.t >= s.t_start)"
            f"{pending} ORDER BY b.id LIMIT ?",
            (before_t, limit),
        )
        if not rows:
            return []
        names = sorted({str(r["body_id"]) for r in rows})
        later: dict[tuple[str, str], list[tuple[int, int]]] = {}
        for o in self._rows(
            f"SELECT id, part, {_NAME} AS name, evaluation FROM bodies"
            f" WHERE id > ? AND {_NAME} IN ({', '.join('?' * len(names))})",
            (rows[0]["id"], *names),
        ):
            later.setdefault((o["part"], o["name"]), []).append((int(o["id"]), o["evaluation"]))
        for r in rows:
            exported = [int(e) for e in str(r.pop("exported") or "").split(",") if e]
            again = [e for i, e in later.get((r["part"], str(r["body_id"])), []) if i > r["id"]]
            r["files"] = sorted(e for e in exported if not again or e > max(again))
        return rows

    def delete_bodies(self, rows: Sequence[int], batch: int = 200) -> int:
        """Delete the bodies `rows` with their evaluations, values and raw data, `batch` bodies
        a transaction (the service's writers wait for one short transaction at most); returns
        how many bodies."""
        rows = list(rows)
        for i in range(0, len(rows), batch):
            chunk = rows[i : i + batch]
            marks = ", ".join("?" * len(chunk))
            with self._tx() as db:
                for table, key in (
                    ("body_values", "body"),
                    ("body_raw", "body"),
                    ("body_evaluations", "body"),
                    ("bodies", "id"),
                ):
                    db.execute(f"DELETE FROM {table} WHERE {key} IN ({marks})", chunk)
        return len(rows)

    def body_raw(self, body_row: int) -> Iterator[dict[str, Any]]:
        """A body's raw data per feature and stop: feature, stop, q_deg (6,), temp_c, sheet and
        edges (n, 3) or None, refused."""
        for r in self._rows(
            "SELECT feature, stop, q_deg, temp_c, sheet, edges, refused FROM body_raw"
            " WHERE body = ? ORDER BY rowid",
            (body_row,),
        ):
            yield {
                "feature": r["feature"],
                "stop": int(r["stop"]),
                "q_deg": _joints(r["q_deg"]),
                "temp_c": r["temp_c"],
                "sheet": points_of(r["sheet"]),
                "edges": points_of(r["edges"]),
                "refused": r["refused"],
            }
