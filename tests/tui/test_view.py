"""The operator's screens as text (app.tui.view): ages on the service's clock, the Log as
readable lines, the knock and its suspect intervals on the Overview."""

from __future__ import annotations

import json
from datetime import UTC, datetime

from app.tui import view

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
        return view.log_rows(
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
    assert view.event_text("window", "not json") == "not json"


def test_the_overview_names_the_knock_and_lists_the_suspect_intervals() -> None:
    interval = {
        "id": 2,
        "start_utc": "2026-11-23T07:41:12+00:00",
        "end_utc": None,
        "size_mm": 0.226,
        "group": "sensor",
        "text": "sensor mount moved",
    }
    attributing = {"flagged_step": {"status": "attributing", "text": "step flagged at 9"}}
    assert "ATTRIBUTING: step flagged at 9" in view.overview_text(attributing)
    corrected = {"flagged_step": {"status": "corrected"}, "suspect_intervals": [interval]}
    assert "last suspect interval 11-23 07:41:12 - OPEN, 0.226 mm (sensor)" in (
        view.overview_text(corrected)
    )
    assert "Knock     none" in view.overview_text({})
    rows = view.suspect_rows([{**interval, "start_utc": "2026-11-23T07:41:12"}])
    assert rows == [("2", "2026-11-23 07:41:12", "OPEN", "0.226", "none", "sensor mount moved")]
    # the bodies measured inside: how many, the first and the last in the row, all on selection
    bodies = {**interval, "bodies": [100412, 100413, 100414]}
    assert view.suspect_rows([bodies])[0][4] == "3: 100412 .. 100414"
    assert view.suspect_rows([{**interval, "bodies": ["B0100412"]}])[0][4] == "1: B0100412"
    assert "bodies 3: 100412 .. 100414" in view.overview_text({"suspect_intervals": [bodies]})
    assert view.suspect_detail(bodies) == (
        "#2 from 2026-11-23 07:41:12 to now (OPEN): 3 bodies: 100412, 100413, 100414"
    )
    assert "no bodies known" in view.suspect_detail(interval)
    assert view.suspect_detail(None) == "no suspect interval selected"
