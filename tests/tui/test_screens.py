"""Screenshots of every pane at 80x24 and 120x40 with frozen data (tests/tui/frozen.py): the
text of each rendered line must equal the stored snapshot (tests/tui/snapshots/). After an
intended change of the screens, regenerate the snapshots and docs/tui/*.svg with
`RVIS_UPDATE_SNAPSHOTS=1 pytest tests/tui/test_screens.py` and review the diff."""

from __future__ import annotations

import asyncio
import html
import os
import re
from pathlib import Path

import pytest

from app.tui.app import PANES
from tests.tui.frozen import FrozenTui

SNAPSHOTS = Path(__file__).parent / "snapshots"
DOCS = Path(__file__).parents[2] / "docs" / "tui"
SIZES = ((80, 24), (120, 40))
_TEXT = re.compile(r'<text [^>]*clip-path="url\(#[\w-]+-line-(\d+)\)"[^>]*>(.*?)</text>')


def screen_lines(svg: str) -> list[str]:
    """The text of each terminal line of a Textual SVG screenshot (trailing blanks dropped)."""
    lines: dict[int, str] = {}
    for row, text in _TEXT.findall(svg):
        lines[int(row)] = lines.get(int(row), "") + html.unescape(text).replace("\xa0", " ")
    return [lines.get(k, "").rstrip() for k in range(max(lines, default=-1) + 1)]


async def screenshot(pane: str, size: tuple[int, int]) -> str:
    app = FrozenTui()
    async with app.run_test(size=size) as pilot:
        await pilot.press(str(PANES.index(pane) + 1))
        await pilot.pause()  # the tab switch asks for a refresh (the pane's history)
        for _ in range(1000):  # until it has landed (the history is read in a thread): 10 s
            if not app.refreshing:
                break
            await pilot.pause(0.01)
        assert not app.refreshing, "the screen did not settle"
        # the widgets it changed are laid out and painted: until two screenshots agree (a table
        # sizes its columns to its rows a frame after they land; on a loaded machine 3 pauses
        # caught the header before it: CI saw the measurements pane's narrow header once)
        shot = ""
        for _ in range(100):
            await pilot.pause(0.02)
            await pilot.wait_for_scheduled_animations()
            again = app.export_screenshot(title=f"rvis tui: {pane}")
            if again == shot:
                break
            shot = again
        return shot


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("pane", PANES)
def test_screen_matches_snapshot(pane: str, size: tuple[int, int]) -> None:
    svg = asyncio.run(screenshot(pane, size))
    lines = screen_lines(svg)
    assert len(lines) == size[1]
    name = f"{pane}_{size[0]}x{size[1]}"
    golden = SNAPSHOTS / f"{name}.txt"
    if os.environ.get("RVIS_UPDATE_SNAPSHOTS"):
        golden.write_text("\n".join(lines) + "\n")
        (DOCS / f"{name}.svg").write_text(svg)
    assert lines == golden.read_text().split("\n")[:-1]


def test_alarm_shows_its_priority_as_text_and_colour() -> None:
    svg = asyncio.run(screenshot("alarms", (80, 24)))
    lines = screen_lines(svg)
    assert any(line.startswith("ALARM MED: drift of P2") for line in lines)
    assert "#ffaf00" in svg  # the medium priority's colour, used only for the active alarm
