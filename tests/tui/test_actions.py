"""What the keys ask before they act (frozen data, attached to no service): resuming moves the
robot in the next window, so it asks first; pausing is sent at once (and, with no service,
refused with a notification)."""

from __future__ import annotations

import asyncio
from typing import Any

from textual.widgets import Label

from app.tui.modals import ConfirmScreen
from tests.tui.frozen import STATUS, FrozenTui
from tests.tui.helpers import press, until


class NotedTui(FrozenTui):
    """FrozenTui keeping the text of every notification."""

    def __init__(self, paused: bool) -> None:
        super().__init__()
        self.status = {**STATUS, "paused": paused, "state": "paused" if paused else "idle"}
        self.notes: list[str] = []

    def notify(self, message: str, **kw: Any) -> None:
        self.notes.append(f"{kw.get('title', '')}: {message}")
        super().notify(message, **kw)


def test_p_resumes_a_paused_service_after_asking() -> None:
    async def scenario() -> None:
        app = NotedTui(paused=True)
        async with app.run_test(size=(80, 24)) as pilot:
            await press(pilot, "p")
            await until(pilot, lambda: bool(app.screen.query("#question")))
            assert isinstance(app.screen, ConfirmScreen)
            question = str(app.screen.query_one("#question", Label).render())
            assert question.startswith("Resume the service?")
            await press(pilot, "y")
            await until(pilot, lambda: bool(app.notes))
            assert app.notes[0].startswith("resume: ")  # sent: no service to answer it

    asyncio.run(scenario())


def test_p_pauses_a_running_service_without_asking() -> None:
    async def scenario() -> None:
        app = NotedTui(paused=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await press(pilot, "p")
            await until(pilot, lambda: bool(app.notes))
            assert app.notes[0].startswith("pause: ")
            assert not isinstance(app.screen, ConfirmScreen)

    asyncio.run(scenario())
