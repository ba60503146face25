"""The simulated line's watch for a hung service (app.sim.line_run `events_until`): silence with
no computing in the process is a hang (TimeoutError); silence while the process computes (a body
rendered on a loaded machine) is waited out, then its events come."""

from __future__ import annotations

import queue
import threading
import time
from types import SimpleNamespace
from typing import Any

import pytest

from app.sim.line_run import SimulatedLineRun


def _events(run: Any, timeout_s: float) -> list[dict[str, Any]]:
    return list(SimulatedLineRun.events_until(run, lambda e: e["event"] == "window", timeout_s))


def test_silence_with_nothing_computed_is_a_hang() -> None:
    run = SimpleNamespace(events=queue.Queue())
    with pytest.raises(TimeoutError, match="no event from the service"):
        _events(run, 0.05)


def test_silence_while_the_process_computes_is_waited_out() -> None:
    run = SimpleNamespace(events=queue.Queue())

    def busy_then_window() -> None:
        end = time.process_time() + 1.0  # a rendered body: computing, no event meanwhile
        x = 0
        while time.process_time() < end:
            x += 1
        run.events.put({"event": "window"})

    worker = threading.Thread(target=busy_then_window)
    worker.start()
    try:
        assert _events(run, 0.5) == [{"event": "window"}]
    finally:
        worker.join(timeout=10.0)
