"""The queue from the service's event bus to the OPC UA server process (issue 39 item 2): alarm
events are kept each and in order, the other events merged; when alarm events fill it the
oldest is dropped, counted (the bus's `lost`, `rvis status`'s `opcua.events_dropped`) and
logged once per 10 s, never blocking the service."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pytest

from app.line.events import EventBus
from app.line.opcua import FEED_NAME
from app.line.opcua.feed import LOG_EVERY_S, TICK, FeedQueue
from app.line.store import Store
from app.sim.line_run import SimulatedLineRun
from drivers.clock import RealClock
from tests.opcua.conftest import Servers, rvis


def _alarm(alarm_id: int, event: str = "alarm", state: str = "raised") -> dict[str, Any]:
    return {"event": event, "t": float(alarm_id), "id": alarm_id, "code": "sensor", "state": state}


def test_alarm_events_in_order_the_others_merged() -> None:
    q = FeedQueue(100)
    for message in (
        {"event": "state", "t": 1.0},
        _alarm(1),
        {"event": "window", "t": 2.0},
        {"event": "stopped", "t": 3.0},
        {"event": "window", "t": 2.5},
        _alarm(1, "alarm_cleared", "cleared"),
    ):
        q.offer(message)
    batch, offered = q.take()
    assert offered == 6 and q.lost == 0
    assert [m["event"] for m in batch] == [TICK, "alarm", TICK, "alarm_cleared"]
    assert batch[2]["t"] == 3.0 and batch[2]["stopped"] is True  # merged: latest, stopped kept
    assert batch[0]["stopped"] is False


def test_a_full_queue_drops_the_oldest_alarm_event_counted_and_logged_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    store = Store(tmp_path / "rvis.db")
    try:
        bus = EventBus(store, RealClock())
        assert bus.lost(FEED_NAME) is None  # no OPC UA server feeds: not in the status reply
        q = FeedQueue(4)
        bus.attach(q)
        caplog.set_level(logging.WARNING, logger="rvis.line.opcua")
        for alarm_id in range(1, 11):  # the server process reads nothing meanwhile
            bus.emit("alarm", {"id": alarm_id, "code": "sensor", "state": "raised"})
            bus.emit("window", {"n": alarm_id})
        batch, _ = q.take()
        kept = [m["id"] for m in batch if m["event"] == "alarm"]
        assert kept and kept == list(range(11 - len(kept), 11))  # the newest, in order
        assert len(batch) <= 4 and all(m["event"] in ("alarm", TICK) for m in batch)
        assert q.lost == 10 - len(kept) and bus.lost(FEED_NAME) == q.lost
        lines = [r for r in caplog.records if "alarm or body event(s) not sent" in r.getMessage()]
        assert len(lines) == 1, f"logged at most once per {LOG_EVERY_S:g} s"
        bus.unsubscribe(q)
        assert bus.lost(FEED_NAME) == 10 - len(kept)  # kept after the server stopped
    finally:
        store.close()


def test_rvis_status_says_what_the_feed_lost(line: SimulatedLineRun, servers: Servers) -> None:
    """With OPC UA servers fed, the status reply carries `opcua.events_dropped` (the sum over
    their queues) and `rvis status` says it in words."""
    assert servers.read_only
    status = json.loads(rvis(line, "status", "--json"))
    assert status["opcua"] == {"events_dropped": line.service.bus.lost(FEED_NAME)}
    assert "alarm or body events lost on the way to the server" in rvis(line, "status")
