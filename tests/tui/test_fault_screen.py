"""Issue 40 item 4: at 80x24 in a fault the status line, the alarm banner and every device's
last error show whole on the rendered screen (wrapped, never cut); with the PLC unreachable the
line's facts read "unknown (PLC unreachable)", not "running NO, PLC heartbeat LOST"."""

from __future__ import annotations

import asyncio

import pytest

from app.config.line import LineSettings
from app.line.cycle import WindowWatch
from app.tui import history_view, view
from drivers.errors import DeviceTimeout
from fakes.clock import VirtualClock
from fakes.devices import FakePlc
from tests.tui.frozen import FAULT_HISTORY, FAULT_STATUS, NOW, STATUS, FrozenTui
from tests.tui.test_screens import screen_lines, screenshot

#: what the Overview must not state while the PLC does not answer
FACTS = ("running NO", "running yes", "LOST", "alive", "window closed")


def rendered(pane: str, size: tuple[int, int] = (80, 24)) -> list[str]:
    """The text of each line of the pane in the fault, as the terminal draws it."""
    app = FrozenTui(FAULT_STATUS, FAULT_HISTORY)
    return screen_lines(asyncio.run(screenshot(pane, size, app=app)))


def shows_whole(lines: list[str], text: str) -> bool:
    """The text is on the screen whole: on one line, or wrapped over lines that follow each
    other (a wrapped line breaks at a space)."""
    screen = " ".join(" ".join(line.split()) for line in lines)
    return " ".join(text.split()) in screen


@pytest.mark.parametrize("pane", ["overview", "devices"])
def test_at_80x24_in_a_fault_the_header_and_the_banner_show_whole(pane: str) -> None:
    lines = rendered(pane)
    header = view.status_line(FAULT_STATUS, True, "", NOW)
    banner, _ = view.banner(FAULT_STATUS)
    assert len(header) > 80 and len(banner) > 80  # cut to one line before
    assert lines[0].startswith("fault (waiting for plc (unreachable)")
    assert shows_whole(lines, header), "\n".join(lines)
    assert shows_whole(lines, banner), "\n".join(lines)
    assert "window unknown" in header  # the PLC unreachable: no window is known


def test_at_80x24_in_a_fault_every_device_error_shows_whole() -> None:
    lines = rendered("devices")
    errors = {f: d["last_error"] for f, d in FAULT_STATUS["devices"].items() if d["last_error"]}
    assert set(errors) == {"plc", "robot"}
    for error in errors.values():
        assert shows_whole(lines, error), "\n".join(lines)
    assert any(line.split()[:2] == ["plc", "UNREACHABLE"] for line in lines if line.strip())


def test_with_the_plc_unreachable_the_overview_says_the_line_is_unknown() -> None:
    lines = rendered("overview", (120, 40))
    text = "\n".join(lines)
    line = next(k for k in lines if k.startswith("Line "))
    words = "Line running unknown, PLC heartbeat unknown, window unknown (PLC unreachable)"
    assert line.split() == words.split()
    assert not any(fact in line for fact in FACTS), line
    assert "Devices   plc UNREACHABLE" in text


@pytest.mark.parametrize(
    ("plc_state", "answered", "why"),
    [
        ("unreachable", False, "PLC unreachable"),
        ("closed", False, "PLC closed"),
        ("fault", False, "no answer from the PLC"),  # its link lost after the start
        ("ok", False, "no answer from the PLC"),  # the status read before the first poll
    ],
)
def test_the_line_is_unknown_while_the_plc_does_not_answer(
    plc_state: str, answered: bool, why: str
) -> None:
    status = {
        **STATUS,
        "window": {**STATUS["window"], "plc_answered": answered},
        "devices": {"plc": {**STATUS["devices"]["plc"], "state": plc_state}},
    }
    overview = view.overview_text(status)
    assert not any(fact in overview for fact in FACTS), overview
    assert f"window unknown ({why})" in overview and "running unknown" in overview
    assert "window unknown" in view.status_line(status, True, "", NOW)
    assert view.line_unknown(status) == why


def test_a_plc_that_answers_states_the_line() -> None:
    """A heartbeat that stopped while the PLC answers is a fact: LOST."""
    window = {**STATUS["window"], "heartbeat_alive": False, "line_running": False}
    status = {**STATUS, "window": window}
    assert "running NO, PLC heartbeat LOST, window closed" in view.overview_text(status)
    assert view.line_unknown(status) is None


def test_a_device_retry_reads_as_a_line_in_the_log() -> None:
    detail = {"attempts": 2, "unreachable": {"plc": "DeviceConnectionError: x: cannot connect"}}
    text = history_view.event_text("device_retry", detail)
    assert text == "try 2: plc unreachable (DeviceConnectionError: x: cannot connect)"


class FlakyPlc(FakePlc):
    """A PLC whose link can fail (`dead`)."""

    dead = False

    def _read_input_words(self) -> tuple[int, int]:
        if self.dead:
            raise DeviceTimeout("no reply in 0.2 s")
        return super()._read_input_words()


def test_the_window_watch_says_whether_the_plc_answered_its_last_exchange() -> None:
    """What the status reply's window.plc_answered reports (app/line/status.py): False before
    the first exchange and after one that failed, though the last inputs read are kept."""
    plc = FlakyPlc(clock=VirtualClock()).open()
    try:
        watch = WindowWatch(plc, VirtualClock(), LineSettings())
        assert not watch.answered and watch.inputs is None
        watch.poll()
        assert watch.answered and watch.inputs is not None
        plc.dead = True
        with pytest.raises(DeviceTimeout):
            watch.poll()
        assert not watch.answered and watch.inputs is not None  # stale: not the line now
        plc.dead = False
        watch.poll()
        assert watch.answered
    finally:
        plc.close()
