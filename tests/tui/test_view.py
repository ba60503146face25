"""The operator's screens as text (app.tui.view): ages on the service's clock, the Log as
readable lines, the knock and its suspect intervals on the Overview."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path

from app.tui import history_view, view

WALL = datetime(2026, 11, 23, 9, 30, tzinfo=UTC)


def test_ages_count_on_the_services_clock_not_the_terminals() -> None:
    """A simulated line's clock runs ahead of the wall clock: the calibration applied 2 h ago
    on the service's clock reads 2 h old, not "0 s" (the terminal's clock is behind it)."""
    status = {
        "state": "idle",
        "step": "waiting for a window",
        "now_utc": "2026-11-23T11:30:00+00:00",
        "calibration": {"version": 3, "applied_utc": "2026-11-23T09:30:00+00:00"},
    }
    now = view.service_now(status)
    assert now == datetime(2026, 11, 23, 11, 30, tzinfo=UTC)
    assert "cal v3 2 h 0 min old" in view.status_line(status, True, "", now)
    assert "cal v3 0 s old" in view.status_line(status, True, "", WALL)  # what it read before
    assert view.service_now({}) is None and view.service_now({"now_utc": "soon"}) is None


def test_the_log_shows_each_event_as_a_line_for_people() -> None:
    def line(kind: str, data: dict[str, object]) -> str:
        return history_view.log_rows(
            [{"utc": "2026-11-23T09:00:00", "kind": kind, "detail": json.dumps(data)}]
        )[0][2]

    window = {"window": 412, "slots": [7, 2], "measured": 2, "rejected": 0, "withdrawn": ""}
    assert line("window", {**window, "overrun": True, "note": ""}) == (
        "window 412: slots [7, 2], measured 2, rejected 0 OVERRUN"
    )
    alarm = {"id": 3, "code": "drift_step", "priority": "high", "message": "step of P1"}
    assert line("alarm", alarm) == "HIGH drift_step: step of P1"
    applied = {"version": 6, "calibration_id": 7, "source": "auto", "uid": None}
    assert line("parameters_applied", applied) == "version 6 in force (auto, calibration 7)"
    interval = {
        "id": 1,
        "state": "closed",
        "start_utc": "2026-11-23T06:29:11+00:00",
        "end_utc": "2026-11-23T06:35:02+00:00",
        "size_mm": 0.2253,
        "group": "sensor",
    }
    assert line("suspect_interval", interval) == (
        "suspect interval 1 closed: from 2026-11-23 06:29:11 to 2026-11-23 06:35:02,"
        " 0.225 mm (sensor)"
    )
    assert line("suspect_interval", {**interval, "bodies": [100007, 100008, 100009]}) == (
        "suspect interval 1 closed: from 2026-11-23 06:29:11 to 2026-11-23 06:35:02,"
        " 0.225 mm (sensor), bodies 3: 100007 .. 100009"
    )
    assert line("started", {"params_version": 1}) == "params_version 1"  # any other kind
    assert "{" not in line(
        "measurement",
        {"target": "P2", "slot": 5, "status": "ok", "residual_mm": 0.0412, "reason": ""},
    )
    assert history_view.event_text("window", "not json") == "not json"


def test_the_overview_names_the_knock_and_lists_the_suspect_intervals() -> None:
    interval = {
        "id": 2,
        "start_utc": "2026-11-23T07:41:12+00:00",
        "end_utc": None,
        "size_mm": 0.226,
        "group": "sensor",
        "text": "sensor mount moved",
    }
    found = {"jump": {"text": "step of the cell since measurement 9", "what": "sensor mount"}}
    assert "CORRECTING: step of the cell since measurement 9: sensor mount" in (
        view.overview_text(found)
    )
    corrected = {"jump": {"closed": True}, "suspect_intervals": [interval]}
    assert "last suspect interval 11-23 07:41:12 - OPEN, 0.226 mm (sensor)" in (
        view.overview_text(corrected)
    )
    assert "Knock     none" in view.overview_text({})
    rows = history_view.suspect_rows([{**interval, "start_utc": "2026-11-23T07:41:12"}])
    assert rows == [("2", "2026-11-23 07:41:12", "OPEN", "0.226", "none", "sensor mount moved")]
    # the bodies measured inside: how many, the first and the last in the row, all on selection
    bodies = {**interval, "bodies": [100412, 100413, 100414]}
    assert history_view.suspect_rows([bodies])[0][4] == "3: 100412 .. 100414"
    assert history_view.suspect_rows([{**interval, "bodies": ["B0100412"]}])[0][4] == "1: B0100412"
    assert "bodies 3: 100412 .. 100414" in view.overview_text({"suspect_intervals": [bodies]})
    assert history_view.suspect_detail(bodies) == (
        "#2 from 2026-11-23 07:41:12 to now (OPEN): 3 bodies: 100412, 100413, 100414"
    )
    assert "no bodies known" in history_view.suspect_detail(interval)
    assert history_view.suspect_detail(None) == "no suspect interval selected"


def test_the_overview_says_maintenance_needed_and_the_history_lists_the_procedures(
    tmp_path: Path,
) -> None:
    """Issue 41: held for maintenance, the Overview's service line says so, what moved and the
    procedure that fits, not a bare FAULT; a procedure recorded running has its own line; the
    history lists the maintenance records (app.tui.history, read-only) as rows."""
    from app.line.maintenance_state import maintenance_json
    from app.line.store import Store
    from app.tui.history import HistoryReader

    store = Store(tmp_path / "rvis.db")
    done = store.start_maintenance(
        {
            "t_start": 1.8e9,
            "event": "sensor",
            "who": "anna",
            "folder": "maintenance/0001-sensor",
            "version_before": 3,
            "before": {"version": 3, "validation_rmse_mm": 0.058},
        }
    )
    store.finish_maintenance(done, 1.8e9 + 2400.0, 4, {"version": 4, "validation_rmse_mm": 0.061})
    store.raise_alarm(1.8e9 + 9000.0, "maintenance", AXIS3_TEXT, "urgent")
    store.start_maintenance(
        {
            "t_start": 1.8e9 + 9600.0,
            "event": "axis",
            "axis": 3,
            "who": "ben",
            "folder": "maintenance/0002-axis3",
            "version_before": 4,
        }
    )
    status = {
        "state": "fault",
        "step": "held for maintenance: run `rvis maintain axis 3`",
        # the status reply's, as app.line.status makes it
        "maintenance": maintenance_json(store.active_alarms(), store.maintenance(), tmp_path),
    }
    store.close()
    lines = view.overview_text(status).splitlines()
    assert lines[0] == (
        "Service   MAINTENANCE NEEDED (fault): likely the motor or encoder of axis 3 replaced (its"
        " zero moved) (J3 zero 0.4935 deg); run `rvis maintain axis 3`"
    )
    assert lines[1] == (
        "Maint.    IN MAINTENANCE: axis (axis 3) since 2027-01-15T10:40:00+00:00, by ben, 0"
        " steps passed, none run yet, folder maintenance/0002-axis3"
    )
    assert not view.overview_text({**status, "maintenance": None}).startswith(
        "Service   MAINTENANCE"
    )
    rows = view.maintenance_rows(HistoryReader(tmp_path / "rvis.db").maintenance())
    assert rows == [
        ("2", "axis 3", "2027-01-15 10:40:00", "RUNNING", "ben", "4 -> -", "- -> -"),
        (
            "1",
            "sensor",
            "2027-01-15 08:00:00",
            "2027-01-15 08:40:00",
            "anna",
            "3 -> 4",
            "0.058 -> 0.061",
        ),
    ]
    assert HistoryReader(tmp_path / "none.db").maintenance() == []


#: a `maintenance` alarm's text (app.line.beyond_knock.change_need's), as an older rvis stored
#: it: no fields beside it
AXIS3_TEXT = (
    "a change of 9.91 mm at the measured spheres, beyond a knock's 1.5 mm: J3 zero moved 0.4935"
    " deg, 3 measurements; likely the motor or encoder of axis 3 replaced (its zero moved) (J3"
    " zero 0.4935 deg); bodies are not measured with this cell: run `rvis maintain axis 3`"
)
