"""A maintenance procedure's hand-over clears the service's alarms through the one writer of
alarm state (app.line.log_store.LogRecords.clear_alarms): each cleared alarm an `alarm_cleared`
event in the same transaction, so a consumer that follows the events (the TUI's history, a
historian reading the events table) learns that it cleared, as when the service clears it
(issue 51 item 4). Was: cleared in the store alone, no event."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from app.commission.files import PARAMS_FILE, PLAN_FILE, SENSOR_FILE
from app.config import load_cell
from app.formats.files import write_json, write_text
from app.formats.params import plain_document
from app.line.statedir import StateDir
from app.line.states import AlarmCode
from app.line.store import Store
from app.maintain.context import MaintenanceContext
from app.maintain.handover import handover
from fakes.clock import VirtualClock

T_HELD = 100.0  # when the service raised the alarms
EPOCH = 1_800_000_000.0


def _context(tmp_path: Path) -> MaintenanceContext:
    """A state directory whose service holds the cell for maintenance (a `maintenance` and a
    `drift_step` alarm, and a `low_disk` one the hand-over has nothing to do with), and a
    procedure's folder with its parameters, plan and sensor ready for the hand-over."""
    cfg = load_cell(None)
    state = StateDir(tmp_path / "state")
    state.root.mkdir()
    folder = state.root / "maintenance" / "0001-sensor"
    folder.mkdir(parents=True)
    model = cfg.model()
    write_json(folder / PARAMS_FILE, plain_document(model, model.nominal_x(), "test"))
    write_text(folder / PLAN_FILE, "{}\n")
    write_text(folder / SENSOR_FILE, "# test\n")
    store = Store(state.db)
    try:
        store.raise_alarm(T_HELD, AlarmCode.MAINTENANCE, "held for maintenance", "urgent")
        store.raise_alarm(T_HELD, AlarmCode.DRIFT_STEP, "a step of 2 mm", "high")
        store.raise_alarm(T_HELD, AlarmCode.LOW_DISK, "90 MB free", "medium")
    finally:
        store.close()
    nothing: Any = None
    return MaintenanceContext(
        cfg=cfg,
        state=state,
        station=nothing,
        confirm=lambda _: True,
        say=lambda _: None,
        sphere_sensor=nothing,
        capture=nothing,
        out_dir=folder,
        clock=VirtualClock(EPOCH),
        event="sensor",
    )


def _read(state: StateDir) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    store = Store.read_only(state.db)
    try:
        return store.alarms(), store.events("alarm_cleared")
    finally:
        store.close()


def test_the_handover_clears_the_alarms_with_an_event_each(tmp_path: Path) -> None:
    ctx = _context(tmp_path)
    result = handover(ctx)
    assert all(c.ok for c in result.checks), result.checks
    alarms, events = _read(ctx.state)
    state_of = {a["code"]: a["state"] for a in alarms}
    assert state_of == {"maintenance": "cleared", "drift_step": "cleared", "low_disk": "raised"}
    cleared = {a["id"]: a for a in alarms if a["state"] == "cleared"}
    # one event per alarm cleared, carrying it as the service's clear does (app.line.states.
    # alarm_event), at the time its row says it cleared
    assert sorted(e["data"]["id"] for e in events) == sorted(cleared)
    for e in events:
        row = cleared[e["data"]["id"]]
        assert e["t"] == row["t_cleared"] == EPOCH
        assert e["data"]["state"] == "cleared" and e["data"]["code"] == row["code"]
        assert e["data"]["message"] == row["message"]
    # run again (after a kill): nothing more to clear, no event twice
    handover(ctx)
    assert len(_read(ctx.state)[1]) == len(events)
