"""Shared by the TUI tests: a simulated service in a temp state directory, and waiting on the
screen's state in a bounded loop (never a bare sleep)."""

from __future__ import annotations

import time
from collections.abc import Callable

from textual.pilot import Pilot
from textual.widgets import Static

from app.tui.app import RvisTui


async def until(pilot: Pilot[None], cond: Callable[[], bool], timeout_s: float = 15.0) -> None:
    """Let the app run until cond() holds; AssertionError (with the screen's status line and
    banner) after timeout_s."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            app = pilot.app
            assert isinstance(app, RvisTui)
            shown = f"{text_of(app, '#status')!r} {text_of(app, '#banner')!r}"
            raise AssertionError(f"condition not met in {timeout_s:g} s; screen: {shown}")
        await pilot.pause(0.05)


def text_of(app: RvisTui, selector: str) -> str:
    return str(app.query_one(selector, Static).render())
