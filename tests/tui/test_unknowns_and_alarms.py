"""Issue 30 item 8: the terminal states no unknown as a fact when it has no reply from the
service; an alarm's text can be read whole (the selected one under the table), with who
acknowledged it; the status line and the Overview say the window in the same words."""

from __future__ import annotations

import asyncio
from pathlib import Path

from app.tui import alarm_view, view
from app.tui.app import RvisTui
from tests.tui.frozen import FrozenTui
from tests.tui.helpers import press, text_of, until

FACTS = ("running NO", "LOST", "all 0 OK", "running yes", "alive")


def test_without_a_service_the_overview_says_unknown(tmp_path: Path) -> None:
    async def scenario() -> None:
        app = RvisTui(tmp_path)  # nothing listens on tmp_path/rvis.sock
        async with app.run_test(size=(100, 30)) as pilot:
            await until(pilot, lambda: "unknown" in text_of(app, "#overview-text"))
            overview = text_of(app, "#overview-text")
            assert text_of(app, "#status").startswith("DISCONNECTED")
            assert not any(fact in overview for fact in FACTS), overview
            assert "Devices   unknown" in overview and "window unknown" in overview
            assert text_of(app, "#pending-title").startswith("pending calibration unknown")

    asyncio.run(scenario())


def test_a_lost_connection_drops_the_last_status(tmp_path: Path) -> None:
    """What the service said before it went away is not shown as the state now."""

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(100, 30)) as pilot:
            await until(pilot, lambda: "all 4 OK" in text_of(app, "#overview-text"))
            await app._on_link(False, "the service closed the connection")
            await until(pilot, lambda: "unknown" in text_of(app, "#overview-text"))
            overview = text_of(app, "#overview-text")
            assert not any(fact in overview for fact in FACTS), overview
            assert app.status is None and text_of(app, "#banner") == ""

    asyncio.run(scenario())


def test_the_selected_alarm_reads_whole_with_who_acknowledged_it() -> None:
    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await press(pilot, "4")
            await until(pilot, lambda: "#7 MED drift" in text_of(app, "#alarm-detail"))
            detail = text_of(app, "#alarm-detail")
            assert "recalibration brought forward" in detail  # cut in the table at 80 columns
            await press(pilot, "down")
            await until(pilot, lambda: "#6 HIGH" in text_of(app, "#alarm-detail"))
            assert "CLEARED UNACK" in text_of(app, "#alarm-detail")
            await press(pilot, "down")
            await until(pilot, lambda: "#5 URGENT" in text_of(app, "#alarm-detail"))
            detail = text_of(app, "#alarm-detail")
            assert "acknowledged by root (uid 0) at 2026-11-23 04:15:30" in detail
            assert detail.rstrip().endswith("after removing the cause")  # the text whole

    asyncio.run(scenario())


def test_the_status_line_and_the_overview_say_the_window_alike() -> None:
    for window, words in (
        ({"open": True, "remaining_s": 12.2, "line_running": True}, "window OPEN 12 s left"),
        ({"open": False, "remaining_s": None, "line_running": True}, "window closed"),
    ):
        status = {"state": "idle", "step": "waiting", "window": window, "calibration": {}}
        assert words in view.status_line(status, True, "")
        assert words in view.overview_text(status)


def test_the_alarm_rows_say_who_acknowledged_and_an_unacknowledged_clear() -> None:
    rows = alarm_view.alarm_rows(
        [
            {"id": 1, "priority": "low", "state": "cleared", "t_acked": None, "text": "x"},
            {
                "id": 2,
                "priority": "low",
                "state": "acked",
                "t_acked": 1.0,
                "acked_uid": 0,
                "acked_utc": "2026-11-23T04:15:30+00:00",
                "text": "y",
            },
        ]
    )
    assert [(r[0], r[2], r[4]) for r in rows] == [
        ("2", "ACKED", "root 04:15"),
        ("1", "CLEARED UNACK", "-"),
    ]


def test_the_selected_suspect_interval_lists_every_body_measured_in_it() -> None:
    """Issue 28 item 4: the table shows how many bodies and the first and last; the selected
    interval's bodies are listed whole under it."""

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(100, 30)) as pilot:
            await until(pilot, lambda: "3 bodies" in text_of(app, "#suspect-detail"))
            assert "#2 from 2026-11-23 07:41:12" in text_of(app, "#suspect-detail")
            assert "100412, 100413, 100414" in text_of(app, "#suspect-detail")
            app.query_one("#suspects-table").focus()
            await press(pilot, "down")
            await until(pilot, lambda: "#1 from" in text_of(app, "#suspect-detail"))
            assert "no bodies known" in text_of(app, "#suspect-detail")

    asyncio.run(scenario())
