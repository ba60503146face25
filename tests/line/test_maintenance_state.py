"""A cell in maintenance as the world sees it (app.line.maintenance_state): the `maintenance`
alarm's texts the service writes (app.line.beyond_knock) read as what moved and the procedures
they name; the Machinery operation mode of a status reply."""

from __future__ import annotations

import json
from pathlib import Path

from app.line.beyond_knock import blind_need, several_need
from app.line.maintenance_state import (
    maintenance_json,
    need_of,
    needed_text,
    operation_mode,
    progress_of,
    progress_text,
)


def test_the_blind_alarm_names_every_procedure() -> None:
    text = blind_need(3, 9).text
    need = need_of({"id": 7, "code": "maintenance", "message": text, "t_raised": 1.8e9})
    assert need["procedures"] == [
        "rvis maintain axis N",
        "rvis maintain sensor",
        "rvis maintain fixture",
    ]
    assert need["what"].startswith(
        "no sphere seen where the parameters put it in 3 windows in a row (9 views rejected"
    )
    assert need["raised_utc"] == "2027-01-15T08:00:00+00:00" and need["text"] == text
    assert needed_text(need).endswith(
        "; run `rvis maintain axis N` or `rvis maintain sensor` or `rvis maintain fixture`"
    )


def test_the_need_is_read_from_the_alarms_fields_not_its_text() -> None:
    """The service stores the need's fields beside the alarm's text (the alarm's `detail`, a
    JSON column): read back as they were written, whatever the text says; an alarm from an
    older database (no fields) is read from its text as before."""
    written = several_need(12.345, 1.5, "J2 zero moved 0.5 deg")
    row = {
        "id": 3,
        "code": "maintenance",
        "message": "an operator's words",
        "t_raised": 1.8e9,
        "detail": json.dumps(written.detail()),
    }
    need = need_of(row)
    assert need["what"] == written.what and need["what"].endswith(": J2 zero moved 0.5 deg")
    assert need["procedures"] == [
        "rvis commission --restart",
        "rvis maintain sensor|axis N|fixture",
    ]
    assert need["moved_mm"] == 12.345 and need["group"] is None
    assert need["text"] == "an operator's words"
    old = need_of({**row, "detail": None, "message": written.text})
    assert old["what"] == written.what and old["procedures"] == list(written.procedures)


def test_the_operation_mode_of_a_status_reply() -> None:
    need = {"needed": {"procedures": ["rvis maintain sensor"]}, "running": None}
    running = {"needed": None, "running": {"event": "sensor"}}
    assert operation_mode({"state": "fault", "maintenance": need}) == "Maintenance"
    assert operation_mode({"state": "stopped", "maintenance": need}) == "Maintenance"
    assert operation_mode({"state": "paused", "maintenance": running}) == "Maintenance"
    assert operation_mode({"state": "idle", "maintenance": running}) == "Processing"
    assert operation_mode({"state": "fault", "maintenance": {"needed": None}}) == "Processing"
    assert operation_mode({"state": "paused"}) == "Processing"
    assert operation_mode({"state": "starting"}) == "None"


def test_a_record_left_running_before_a_later_hand_over_is_not_in_maintenance() -> None:
    """A procedure begun again with `--restart` leaves its first record running: once the
    second handed the cell back, the cell is not in maintenance."""
    row = {"event": "axis", "axis": 3, "who": "ben", "t_start": 1.8e9, "folder": "f"}
    first = {**row, "id": 1, "status": "running"}
    second = {**row, "id": 2, "status": "done", "t_end": 1.8e9 + 60.0, "version_after": 2}
    m = maintenance_json([], [first, second], None)
    assert m["running"] is None and m["last_done"]["id"] == 2
    third = {**row, "id": 3, "status": "running"}
    m = maintenance_json([], [first, second, third], None)
    assert m["running"]["id"] == 3 and "progress" not in m["running"]  # no folder read


def test_a_step_not_run_is_done_but_not_counted_as_passed(tmp_path: Path) -> None:
    """A sensor procedure on the geometric path: its acceptance journalled "not run" (issue 51
    item 2); the progress goes on past it and says so."""
    step = {"started_utc": "2027-01-15T08:05:00+00:00", "seconds": 1.0, "checks": [], "files": []}
    steps = [
        {**step, "name": name, "status": "passed", "results": {}}
        for name in ("devices", "prepare", "sensor", "handeye")
    ]
    steps.append({**step, "name": "acceptance", "status": "not run", "results": {}})
    steps.append({**step, "name": "workspace", "status": "started", "results": {}})
    (tmp_path / "journal.json").write_text(json.dumps({"steps": steps}))
    progress = progress_of(tmp_path)
    assert progress["steps_passed"] == 4 and progress["not_run"] == ["acceptance"]
    assert (progress["next_step"], progress["next_status"]) == ("workspace", "started")
    assert progress_text(progress) == (
        "4 steps passed, 1 not run (acceptance), next: workspace (started)"
    )
