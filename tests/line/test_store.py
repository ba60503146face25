"""The SQLite store: migrations, round trips, alarm life cycle, and crash safety (kill -9 of a
writer: every acknowledged row is there and the file is intact)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.line.states import suspect_json
from app.line.store import MIGRATIONS, SCHEMA_VERSION, StorageError, Store


def _row(k: int) -> dict[str, object]:
    return {
        "t": float(k),
        "window": k,
        "slot": k % 24,
        "target": f"P{k % 4 + 1}",
        "q_deg": [float(k), 0, 0, 0, -90, 0],
        "c_sensor_mm": [1.0, 2.0, 130.0 + k],
        "status": "ok",
        "quality": {"rms_mm": 0.01},
        "params_version": 1,
        "residual_mm": 0.05,
        "next_position": (k + 1) % 24,
    }


def test_new_database_is_migrated_to_the_schema_version_in_wal_mode(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION == len(MIGRATIONS)
    store.close()
    db = sqlite3.connect(tmp_path / "rvis.db")
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"measurements", "calibrations", "applied", "alarms", "events", "actions"} <= tables
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    db.close()


def test_a_failing_migration_leaves_the_previous_version(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    bad = (*MIGRATIONS, ("CREATE TABLE extra (a INTEGER)", "THIS IS NOT SQL"))
    with pytest.raises(sqlite3.OperationalError):
        store.migrate(bad)
    assert store.version() == SCHEMA_VERSION
    good = (*MIGRATIONS, ("CREATE TABLE extra (a INTEGER)",))
    assert store.migrate(good) == SCHEMA_VERSION + 1
    store.close()
    assert Store(tmp_path / "rvis.db").version() == SCHEMA_VERSION + 1  # reopening: no-op


def test_a_version_1_database_gains_the_temperature_column_and_keeps_its_rows(
    tmp_path: Path,
) -> None:
    db = sqlite3.connect(tmp_path / "rvis.db")
    for sql in MIGRATIONS[0]:
        db.execute(sql)
    db.execute(
        "INSERT INTO measurements (t, window, slot, target, q_deg, c_sensor_mm, status)"
        " VALUES (1.0, 1, 0, 'P1', '[0, 0, 0, 0, 0, 0]', '[1, 2, 3]', 'ok')"
    )
    db.execute("PRAGMA user_version = 1")
    db.commit()
    db.close()
    store = Store(tmp_path / "rvis.db")  # an older service's state directory
    assert store.version() == SCHEMA_VERSION == 11
    (old,) = store.measurements()
    assert old["c_sensor_mm"] == [1, 2, 3] and old["temp_c"] is None
    store.add_measurement({**_row(1), "temp_c": 23.45})
    assert store.measurements()[-1]["temp_c"] == 23.45
    store.close()


def test_measurements_round_trip_and_move_the_schedule_position(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    ids = [store.add_measurement(_row(k)) for k in range(3)]
    rejected = {**_row(3), "status": "rejected", "c_sensor_mm": None, "reason": "NoStripe"}
    store.add_measurement(rejected)
    rows = store.measurements()
    assert [r["id"] for r in rows] == ids
    assert [r["id"] for r in store.measurements(last=2)] == ids[1:]
    assert [r["id"] for r in store.measurements(since_id=ids[0], last=5)] == ids[1:]
    assert rows[2]["c_sensor_mm"] == [1.0, 2.0, 132.0] and rows[2]["q_deg"][0] == 2.0
    assert store.measurements(status="rejected")[0]["reason"] == "NoStripe"
    assert store.counts() == {"ok": 3, "rejected": 1}
    assert store.schedule_position() == (4, 3)
    reader = Store.read_only(tmp_path / "rvis.db")  # a committed row is visible to others
    assert len(reader.measurements()) == 3
    with pytest.raises(StorageError, match="readonly"):
        reader.add_event(0.0, "x", {})
    reader.close()
    store.close()


def test_an_alarm_that_cleared_unacknowledged_can_still_be_acknowledged(tmp_path: Path) -> None:
    """ISA-18.2: an alarm that returned to normal before anybody acknowledged it is still
    unacknowledged; acknowledging it records who and when, and it stays cleared."""
    store = Store(tmp_path / "rvis.db")
    a = store.raise_alarm(1.0, "plc_heartbeat", "PLC heartbeat lost", "high")
    assert len(store.clear_alarms(2.0, "plc_heartbeat")) == 1
    assert store.ack_alarm(a, 3.0, uid=1000)
    assert not store.ack_alarm(a, 4.0, uid=1001)  # once
    (row,) = store.alarms()
    assert (row["state"], row["t_acked"], row["acked_uid"]) == ("cleared", 3.0, 1000)
    assert store.active_alarms() == []
    store.close()


def test_alarm_life_cycle(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    a = store.raise_alarm(1.0, "drift", "drift of P1", "medium")
    assert store.raise_alarm(2.0, "drift", "again") == a  # one active alarm per code
    assert store.ack_alarm(a, 3.0, uid=1000) and not store.ack_alarm(a, 4.0, uid=1000)
    assert store.shelve_alarm(a, 100.0, "maintenance")
    assert store.active_alarms()[0]["state"] == "shelved"
    assert len(store.clear_alarms(5.0, "drift")) == 1
    assert store.active_alarms() == []
    (row,) = store.alarms()
    assert (row["acked_uid"], row["shelve_reason"], row["state"]) == (
        1000,
        "maintenance",
        "cleared",
    )
    store.close()


def test_a_clearing_is_written_with_its_event_in_one_transaction(tmp_path: Path) -> None:
    """The one writer of a clearing (the service's faults and a maintenance hand-over use it):
    each alarm cleared with its `alarm_cleared` event carrying it, or neither (issue 51 item 4:
    the hand-over cleared the rows alone, and a consumer of the events never learnt it)."""
    store = Store(tmp_path / "rvis.db")
    a = store.raise_alarm(1.0, "maintenance", "held for maintenance", "urgent")
    b = store.raise_alarm(1.5, "low_disk", "90 MB free", "medium")
    assert store.clear_alarms(2.0, "spc") == []  # none active: nothing written
    (data,) = store.clear_alarms(3.0, "maintenance")
    assert (data["id"], data["code"], data["state"]) == (a, "maintenance", "cleared")
    (event,) = store.events("alarm_cleared")
    assert event["t"] == 3.0 and event["data"] == data
    # a failure in the transaction leaves the alarm active and no event
    store._db.execute(
        "CREATE TEMP TRIGGER fail BEFORE INSERT ON events"
        " BEGIN SELECT RAISE(ABORT, 'no events'); END"
    )
    with pytest.raises(sqlite3.IntegrityError):
        store.clear_alarms(4.0)
    store._db.execute("DROP TRIGGER fail")
    assert [x["id"] for x in store.active_alarms()] == [b]
    assert len(store.events("alarm_cleared")) == 1
    store.close()


WRITER = """
import sys
from app.line.store import Store
from tests.line.test_store import _row
store = Store(sys.argv[1])
k = 0
while True:
    row_id = store.add_measurement(_row(k))
    print(row_id, flush=True)   # the acknowledgement comes after the commit
    k += 1
"""


@pytest.mark.parametrize("n_acks", [1, 7, 40])
def test_kill_9_loses_no_acknowledged_measurement(tmp_path: Path, n_acks: int) -> None:
    path = tmp_path / "rvis.db"
    Store(path).close()
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, cwd=root, text=True
    )
    assert proc.stdout is not None
    acked = [int(proc.stdout.readline()) for _ in range(n_acks)]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    store = Store(path)
    assert store.integrity_ok()
    stored = {r["id"] for r in store.measurements()}
    assert set(acked) <= stored
    assert store.schedule_position()[1] >= max(acked) - 1  # position committed with the row
    store.close()


def test_shelved_alarms_return_when_their_time_is_up(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    a = store.raise_alarm(0.0, "drift", "drift of P1")
    b = store.raise_alarm(0.0, "plc_heartbeat", "lost")
    assert store.shelve_alarm(a, 100.0, "known") and store.shelve_alarm(b, 200.0, "known")
    assert store.unshelve_expired(99.0) == []
    assert store.unshelve_expired(150.0) == [a]
    assert [r["state"] for r in store.active_alarms()] == ["raised", "shelved"]
    store.close()


def test_suspect_intervals_open_update_close_and_list_by_time(tmp_path: Path) -> None:
    """Migration 4: suspect intervals; open ones are listed whatever `since`, closed ones when
    they end at or after it; before_id selects the measurements before a change point."""
    store = Store(tmp_path / "rvis.db")
    ids = [store.add_measurement(_row(k)) for k in range(4)]
    assert [r["id"] for r in store.measurements(before_id=ids[2])] == ids[:2]
    assert [r["id"] for r in store.measurements(before_id=ids[2], last=1)] == [ids[1]]
    first = store.open_suspect(
        {"t_start": 100.0, "last_good_id": ids[1], "onset_id": ids[2], "params_version": 3}
    )
    store.update_suspect(first, size_mm=0.31, group_name="sensor", text="sensor mount moved")
    store.update_suspect(first, t_end=160.0, end_reason="step", end_version=4, calibration_id=2)
    second = store.open_suspect({"t_start": 500.0, "onset_id": ids[3], "text": "flagged"})
    rows = store.suspects()
    assert [r["id"] for r in rows] == [first, second]
    assert rows[0]["size_mm"] == 0.31 and rows[0]["t_end"] == 160.0 and rows[1]["t_end"] is None
    assert [r["id"] for r in store.suspects(since_t=200.0)] == [second]  # open: always
    assert [r["id"] for r in store.suspects(since_t=150.0)] == [first, second]
    assert [r["id"] for r in store.suspects(last=1)] == [second]
    with pytest.raises(ValueError, match="unknown"):
        store.update_suspect(first, bodies=[1])
    store.close()


def test_an_older_database_read_only_has_no_suspect_intervals(tmp_path: Path) -> None:
    """`rvis status` / `rvis state suspects` before a new service migrated an old database."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for migration in MIGRATIONS[:3]:
        for sql in migration:
            db.execute(sql)
    db.execute("PRAGMA user_version = 3")
    db.commit()
    db.close()
    store = Store.read_only(tmp_path / "rvis.db")
    assert store.version() == 3 and store.suspects() == []
    store.close()


def test_a_suspect_intervals_bodies_are_those_of_the_windows_inside_it(tmp_path: Path) -> None:
    """Migration 5: the clamp windows with their bodies. An interval's bodies are the non-null
    body ids of the windows from its start to its end, both included (an open one: up to now),
    in time order, each once (a window the PLC gave back keeps its body); in the rows of
    `suspects` and `suspect`, and in suspect_json."""
    store = Store(tmp_path / "rvis.db")
    onset = store.add_measurement(_row(1))
    closed = store.open_suspect({"t_start": 100.0, "onset_id": onset})
    store.update_suspect(closed, t_end=160.0, end_reason="step")
    opened = store.open_suspect({"t_start": 500.0, "onset_id": onset})
    assert [r["bodies"] for r in store.suspects()] == [[], []]
    windows: list[tuple[float, int | str | None]] = [(90.0, 1), (100.0, 2), (130.0, 3)]
    windows += [(135.0, 3), (140.0, None), (160.0, 4)]
    windows += [(170.0, 5), (499.0, 6), (510.0, "B0000007"), (520.0, 8)]
    for t, body in windows:
        store.add_window(t, body)
    assert [(w["t"], w["body_id"]) for w in store.windows()] == windows
    rows = store.suspects()
    assert [r["bodies"] for r in rows] == [[2, 3, 4], ["B0000007", 8]]
    one = store.suspect(opened)
    assert one is not None and one["bodies"] == ["B0000007", 8]
    assert [r["bodies"] for r in store.suspects(last=1)] == [["B0000007", 8]]
    assert [r["bodies"] for r in store.suspects(since_t=200.0)] == [["B0000007", 8]]
    assert suspect_json(rows[0])["bodies"] == [2, 3, 4]  # the body numbers stay numbers
    assert suspect_json({"id": 1, "t_start": 1.0})["bodies"] == []
    store.close()


def test_a_version_4_database_gains_the_windows_and_keeps_its_suspect_intervals(
    tmp_path: Path,
) -> None:
    """Read-only before a service of this rvis migrated it, a version 4 database lists its
    intervals without bodies; opened by the service it gains the windows table (migration 5)
    and every row it had."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for migration in MIGRATIONS[:4]:
        for sql in migration:
            db.execute(sql)
    db.execute(
        "INSERT INTO suspect_intervals (t_start, t_end, onset_id, size_mm, text)"
        " VALUES (100.0, 160.0, 7, 0.31, 'sensor mount moved')"
    )
    db.execute("PRAGMA user_version = 4")
    db.commit()
    db.close()
    old = Store.read_only(tmp_path / "rvis.db")
    (row,) = old.suspects()
    assert old.version() == 4 and row["bodies"] == [] and row["size_mm"] == 0.31
    assert old.windows() == []
    old.close()
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION == 11
    (row,) = store.suspects()
    assert (row["t_end"], row["text"], row["bodies"]) == (160.0, "sensor mount moved", [])
    store.add_window(120.0, 100001)
    assert store.suspects()[0]["bodies"] == [100001]
    store.close()


def test_a_version_5_database_gains_the_windows_u95_and_keeps_its_windows(tmp_path: Path) -> None:
    """Migration 5 -> 6: the U95 stated for each window's bodies (app.line.accuracy); the
    windows recorded before it have none."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for step in MIGRATIONS[:5]:
        for sql in step:
            db.execute(sql)
    db.execute("INSERT INTO windows (t, body_id) VALUES (1.0, 7)")
    db.execute("PRAGMA user_version = 5")
    db.commit()
    db.close()
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION == 11
    store.add_window(2.0, 8)
    store.state_window_u95(0.093)
    assert [(w["body_id"], w["u95_mm"]) for w in store.windows()] == [(7, None), (8, 0.093)]
    store.close()


def test_a_version_7_database_keeps_its_maintenance_records_and_may_abandon_one(
    tmp_path: Path,
) -> None:
    """Schema 8 rebuilds the maintenance table for the 'abandoned' status (`rvis maintain
    --restart`); the records of a version 7 database are kept as they were."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for k in range(7):
        for sql in MIGRATIONS[k]:
            db.execute(sql)
    db.execute(
        "INSERT INTO maintenance (t_start, event, axis, who, folder, status, version_before)"
        " VALUES (5.0, 'axis', 3, 'eng', 'maintenance/0001-axis3', 'running', 4)"
    )
    db.execute("PRAGMA user_version = 7")
    db.commit()
    db.close()
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION
    (row,) = store.maintenance()
    assert (row["event"], row["axis"], row["status"], row["version_before"]) == (
        "axis",
        3,
        "running",
        4,
    )
    store.abandon_maintenance(int(row["id"]), 9.0, "begun again")
    (row,) = store.maintenance()
    assert row["status"] == "abandoned" and row["t_end"] == 9.0
    assert row["after"] == {"reason": "begun again"}
    store.close()


def test_a_body_is_stored_with_its_raw_data_and_evaluated_again_beside(tmp_path: Path) -> None:
    """Migration 8 -> 9: bodies, their values by evaluation and their raw points; a version 8
    database keeps its rows. A second evaluation is added beside the first, never over it."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for step in MIGRATIONS[:8]:
        for sql in step:
            db.execute(sql)
    db.execute("INSERT INTO windows (t, body_id) VALUES (1.0, 7)")
    db.execute("PRAGMA user_version = 8")
    db.commit()
    db.close()
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION == 11 and len(store.windows()) == 1
    value = {
        "feature": "H01", "characteristic": "X", "kind": "position", "nominal_mm": 10.0,
        "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": 10.02, "u95_mm": 0.06,
        "decision": "conforming", "reason": "",
    }  # fmt: skip
    first = {"t": 5.0, "params_version": 3, "statement_u95_mm": 0.08, "reason": "measured",
             "ok": 1, "n_nok": 0, "n_undecided": 0, "n_not_measured": 0}  # fmt: skip
    sheet = np.arange(12, dtype=float).reshape(4, 3) + 0.125
    raw: list[dict[str, Any]] = [
        {"feature": "H01", "q_deg": np.arange(6.0), "temp_c": 21.5, "sheet": sheet,
         "edges": sheet[:2], "refused": ""},
        {"feature": "H02", "q_deg": np.ones(6), "temp_c": None, "sheet": None, "edges": None,
         "refused": "plane: 3 points on the sheet"},
        # migration 9 -> 10: a feature measured from a second stop (app.inspect.views)
        {"feature": "H01", "stop": 1, "q_deg": np.arange(6.0), "temp_c": 21.5,
         "sheet": sheet + 1.0, "edges": sheet[:2], "refused": ""},
    ]  # fmt: skip
    row = store.add_body(
        {"t": 5.0, "body_id": 100012, "part": "P", "window": 2}, first, [value], raw
    )
    again = {**first, "t": 9.0, "params_version": 4, "reason": "step corrected", "suspect_id": 1,
             "decisions_changed": 1, "ok": 0, "n_nok": 1}  # fmt: skip
    assert store.add_evaluation(row, again, [{**value, "measured_mm": 10.7,
                                                "decision": "nonconforming"}]) == 1  # fmt: skip
    (b,) = store.bodies(body_id="100012")
    assert (b["evaluation"], b["ok"], b["params_version"], b["reason"]) == (
        1,
        0,
        4,
        "step corrected",
    )
    assert store.body_values(row)[0]["measured_mm"] == 10.7
    assert store.body_values(row, 0)[0]["measured_mm"] == 10.02
    assert [e["evaluation"] for e in store.body_evaluations(row)] == [0, 1]
    h01, h02, h01b = store.body_raw(row)
    assert np.array_equal(h01["sheet"], sheet) and np.array_equal(h01["q_deg"], np.arange(6.0))
    assert h02["sheet"] is None and h02["refused"].startswith("plane")
    assert (h01["stop"], h02["stop"], h01b["stop"]) == (0, 0, 1)
    assert np.array_equal(h01b["sheet"], sheet + 1.0)
    assert store.bodies(since_t=6.0) == []
    store.close()


def test_a_version_10_database_gains_the_alarms_detail_and_keeps_its_alarms(
    tmp_path: Path,
) -> None:
    """An older service's `maintenance` alarm keeps its text (read as before, app.line.
    maintenance_state); a new one carries its fields beside it, read back as written."""
    db = sqlite3.connect(tmp_path / "rvis.db")
    for step in MIGRATIONS[:10]:
        for sql in step:
            db.execute(sql)
    db.execute(
        "INSERT INTO alarms (code, priority, message, state, t_raised)"
        " VALUES ('maintenance', 'urgent', 'a change; likely x; run `rvis maintain sensor`',"
        " 'raised', 1.0)"
    )
    db.execute("PRAGMA user_version = 10")
    db.commit()
    db.close()
    store = Store(tmp_path / "rvis.db")
    assert store.version() == SCHEMA_VERSION == 11
    (old,) = store.active_alarms()
    assert old["detail"] is None and old["message"].startswith("a change")
    store.clear_alarms(2.0)
    detail = {"what": "likely y", "procedures": ["rvis maintain fixture"], "group": "fixture"}
    new = store.raise_alarm(3.0, "maintenance", "text", "urgent", detail)
    row = store.alarm(new)
    assert row is not None and json.loads(row["detail"]) == detail
    store.close()


def test_a_versions_measurements_are_its_newest_run_of_good_rows(tmp_path: Path) -> None:
    """The estimator's replay on a restart (app.line.estimate): every good row measured with
    the version in force since it was last put in force, however many (the window's bound
    does not cut it), its rejected rows left out; a version put in force again (a rollback)
    starts a new run, empty until it measures (its old run is another period of the cell's)."""
    store = Store(tmp_path / "rvis.db")
    ids: list[int] = []

    def measure(versions: list[int]) -> None:
        for v in versions:
            k = len(ids)
            status = "rejected" if k % 7 == 0 else "ok"
            c = None if status == "rejected" else [1.0, 2.0, 130.0]
            ids.append(store.add_measurement(_row(k) | {"params_version": v, "status": status,
                                                         "c_sensor_mm": c}))  # fmt: skip

    def good(first: int) -> list[int]:
        return [i for k, i in enumerate(ids) if k >= first and k % 7]

    measure([1] * 3)
    measure([2] * 200)
    assert [r["id"] for r in store.measurements_of_version(2)] == good(3)  # in force
    # the rollback to 1: its run of 3 rows is before 2's, none since it is in force again
    assert store.measurements_of_version(1) == []
    measure([1] * 5)
    assert [r["id"] for r in store.measurements_of_version(1)] == good(203)
    assert store.measurements_of_version(3) == []
    store.close()
