"""Issue 49 item 3's must-show: the TUI (Textual's Pilot, at 80x24) shows a NOK body's row red
within 1 s of the body's event, against a REAL running service: the simulated line measuring
every clamped body by the simulated part type's feature plan, with a process shift of feature
H01 (0.8 mm along its normal and in its sheet from the first body on: H01.Z out of its +-0.5 mm
tolerance by more than its U95, so every body is NOK). The service's `body` event follows the
body's last feature by the robot's way home and the storing (a few tens of ms at this pace).

The line runs at time x40 with no idle time skipped (the body phase lies between the windows),
a body about every 1.5 s of real time; each wait is on an event or the screen, never a sleep.
"""

from __future__ import annotations

import asyncio
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from textual.widgets import DataTable

from app.config import load_cell
from app.sim.line_run import SimulatedLineRun
from app.sim.part import ensure_features
from app.sim.tui_line import TuiSimSettings, simulated_service
from app.tui.app import RvisTui
from app.tui.bodies import BodiesPane
from app.tui.body_view import DECISION_STYLE, NOK_STYLE
from tests.tui.helpers import press, until

SIM = TuiSimSettings(geometric=True, seed=3, scale=40.0)
#: generous: a body comes every 1.5 s
WAIT_S = 60.0
#: the issue's bound [s]: a NOK body on screen within it
SHOWN_WITHIN_S = 1.0
NOK_BODIES = 3


@pytest.fixture
def service(tmp_path: Path) -> Iterator[SimulatedLineRun]:
    cfg = load_cell(None)
    cfg = replace(
        cfg,
        simline=replace(cfg.simline, shift_feature="H01", shift_at_body=0, shift_mm=0.8),
    )
    ensure_features(tmp_path, cfg)
    with simulated_service(cfg, tmp_path, SIM) as run:
        yield run


class BodyEvents:
    """The service's `body` events as they are emitted, each with the moment it came
    (time.monotonic), collected by a thread of its own from the service's event bus."""

    def __init__(self, run: SimulatedLineRun) -> None:
        self.run = run
        self.seen: list[tuple[float, dict[str, Any]]] = []
        self._events = run.service.bus.subscribe()
        self._thread = threading.Thread(target=self._follow, name="body-events", daemon=True)

    def __enter__(self) -> BodyEvents:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._events.put({"event": "end"})
        self._thread.join()
        self.run.service.bus.unsubscribe(self._events)

    def _follow(self) -> None:
        while (event := self._get())["event"] != "end":
            if event["event"] == "body":
                self.seen.append((time.monotonic(), event))

    def _get(self) -> dict[str, Any]:
        try:
            return self._events.get(timeout=WAIT_S)
        except queue.Empty:
            return {"event": "end"}


def shown_red(app: RvisTui, body_id: Any, key: str) -> bool:
    """The Bodies pane shows this body NOK, and its characteristic `key` in a row on screen
    (the nonconforming ones come first), every cell of it in the nonconforming colour."""
    head = app.query_one(BodiesPane).head
    if not head.plain.startswith(f"Body {body_id} ") or NOK_STYLE not in _styles(head):
        return False
    table: DataTable[Any] = app.query_one("#bodies-table", DataTable)
    keys = [str(table.get_row_at(k)[0]).strip() for k in range(table.row_count)]
    if key not in keys or keys.index(key) >= table.size.height - 1:  # under its header
        return False
    red = {DECISION_STYLE["nonconforming"]}
    return all(_styles(c) == red for c in table.get_row_at(keys.index(key)))


def _styles(text: Any) -> set[str]:
    return {str(span.style) for span in getattr(text, "spans", [])}


def test_a_nok_body_is_on_screen_red_within_1_s_of_its_event(service: SimulatedLineRun) -> None:
    async def scenario() -> list[float]:
        app = RvisTui(service.state_dir)
        delays = []
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.client.connected and app.status is not None, WAIT_S)
            await press(pilot, "7")
            await until(pilot, lambda: app.pane == "bodies", WAIT_S)
            with BodyEvents(service) as events:
                for n in range(NOK_BODIES):
                    await until(pilot, lambda: len(events.seen) > n, WAIT_S)  # noqa: B023
                    t_event, event = events.seen[n]
                    assert not event["ok"] and event["worst"]["decision"] == "nonconforming"
                    key = event["worst"]["characteristic"]  # H01's, or a body's own outlier
                    left_s = SHOWN_WITHIN_S - (time.monotonic() - t_event)
                    await until(
                        pilot,
                        lambda: shown_red(app, event["body_id"], key),  # noqa: B023
                        max(left_s, 0.0),
                    )
                    delays.append(time.monotonic() - t_event)
        return delays

    delays = asyncio.run(scenario())
    assert len(delays) == NOK_BODIES and max(delays) <= SHOWN_WITHIN_S, delays
