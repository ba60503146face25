"""Issue 40 item 4: the screen keys from every focus. 1-7 switch panes and q quits whatever has
the focus (a table, the tabs, after any number of Tabs in any pane), except in a filter box,
where they are typed; Escape leaves the box (the focus back on the pane's table), Enter applies
the filter and leaves it too; while a dialog asks, the screen keys do nothing. The terminal
shows frozen data (no service runs here), so Pilot.press waits for each key to be handled."""

from __future__ import annotations

import asyncio

import pytest
from textual.app import ComposeResult
from textual.pilot import Pilot
from textual.widgets import DataTable
from textual.widgets._footer import FooterKey

from app.tui.keys import PANE_FILTER, PANE_FOCUS, PANES, FilterInput, KeysFooter
from app.tui.modals import ConfirmScreen
from tests.tui.frozen import FrozenTui
from tests.tui.helpers import until


def key_of(pane: str) -> str:
    return str(PANES.index(pane) + 1)


def focus_of(app: FrozenTui) -> str:
    """What has the focus: a widget's id, else its type ("ContentTabs", "VerticalScroll")."""
    focused = app.focused
    return "nothing" if focused is None else focused.id or type(focused).__name__


async def focused(pilot: Pilot[None], app: FrozenTui, focus: str) -> None:
    await until(pilot, lambda: focus_of(app) == focus, 5.0)


async def shown(pilot: Pilot[None], app: FrozenTui, pane: str) -> None:
    await until(pilot, lambda: app.pane == pane, 5.0)


async def focuses_by_tab(pilot: Pilot[None], app: FrozenTui, pane: str) -> list[str]:
    """Every focus that Tab reaches in a pane (in Tab order, until it comes round again)."""
    await pilot.press(key_of(pane))
    await until(pilot, lambda: app.pane == pane and focus_of(app) == PANE_FOCUS[pane])
    seen = [focus_of(app)]
    for _ in range(10):
        await pilot.press("tab")
        if focus_of(app) == seen[0]:
            return seen
        seen.append(focus_of(app))
    raise AssertionError(f"Tab never came round in {pane}: {seen}")


@pytest.mark.slow
def test_the_screen_keys_switch_panes_from_every_focus() -> None:
    """From each pane, after 0, 1, 2 ... Tabs (a filter box left with Escape first), the key
    of another pane shows that pane (on the previous build the key did nothing after Tab Tab
    in Calibrations, or Tab in Log: the hidden table handed the focus to a sibling in its
    pane, and the tabs showed that pane again), and so does 7, the bodies' key (issue 49 item
    3: the operator's view of the bodies is reachable from every screen, whatever has the
    focus there). One walk over the panes and their focuses for both keys."""
    assert key_of("bodies") == "7"

    async def at(pilot: Pilot[None], app: FrozenTui, pane: str, tabs: int, focus: str) -> None:
        await pilot.press(key_of(pane), *["tab"] * tabs)
        await focused(pilot, app, focus)
        if focus in PANE_FILTER.values():
            await pilot.press("escape")
            await focused(pilot, app, PANE_FOCUS[pane])

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            for k, pane in enumerate(PANES):
                other = PANES[(k + 3) % len(PANES)]
                for tabs, focus in enumerate(await focuses_by_tab(pilot, app, pane)):
                    await at(pilot, app, pane, tabs, focus)
                    await pilot.press(key_of(other))
                    await shown(pilot, app, other)
                    assert focus_of(app) == PANE_FOCUS[other], (pane, tabs, focus)
                    await at(pilot, app, pane, tabs, focus)
                    await pilot.press("7")
                    await shown(pilot, app, "bodies")
                    assert focus_of(app) == "bodies-table", (pane, tabs, focus)

    asyncio.run(scenario())


def test_in_calibrations_after_tab_tab_the_keys_switch_panes() -> None:
    """The issue's case, whatever the focus a pane's key gives."""

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("3")
            await shown(pilot, app, "calibrations")
            await pilot.press("tab", "tab", "5")
            await shown(pilot, app, "devices")

    asyncio.run(scenario())


@pytest.mark.parametrize("pane", PANES)
def test_q_quits_after_tab_tab(pane: str) -> None:
    """In every pane after Tab Tab (a filter box left with Escape first) q quits."""

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press(key_of(pane))
            await shown(pilot, app, pane)
            await pilot.press("tab", "tab")
            if isinstance(app.focused, FilterInput):
                await pilot.press("escape")
            await pilot.press("q")
            await until(pilot, lambda: not app.is_running, 5.0)

    asyncio.run(scenario())


def test_a_filter_takes_digits_and_q_and_escape_leaves_it() -> None:
    """In the Log's filter box 1-6 and q are typed (a sphere filter needs "P2"); Escape
    gives the focus back to the log's table and the keys act again."""

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("6", "tab", "tab")
            box = app.query_one("#log-filter", FilterInput)
            await until(pilot, lambda: app.focused is box)
            await pilot.press("q", "1", "6")
            await until(pilot, lambda: box.value == "q16")
            assert app.is_running and app.pane == "log"
            footer = {k: b.binding.description for k, b in app.screen.active_bindings.items()}
            assert footer.get("escape") == "Leave filter" and "q" not in footer  # what it shows
            await pilot.press("escape")
            await until(pilot, lambda: focus_of(app) == "log-table")
            assert box.value == "q16"  # left as typed: it filters the log
            await pilot.press("1")
            await until(pilot, lambda: app.pane == "overview")

    asyncio.run(scenario())


def test_slash_goes_to_the_filter_and_enter_applies_it_and_leaves() -> None:
    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2", "slash")
            box = app.query_one("#sphere-filter", FilterInput)
            await until(pilot, lambda: app.focused is box)
            await pilot.press("P", "2", "enter")
            table = app.query_one("#measurements-table", DataTable)
            await until(pilot, lambda: app.focused is table)
            assert box.value == "P2"
            await pilot.press("3")
            await until(pilot, lambda: app.pane == "calibrations")
            await pilot.press("slash")  # no filter box in Calibrations: nothing happens
            await pilot.pause()
            assert focus_of(app) == PANE_FOCUS["calibrations"]

    asyncio.run(scenario())


def test_while_a_dialog_asks_the_screen_keys_do_nothing() -> None:
    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("5", "r")  # reset asks first
            await until(pilot, lambda: isinstance(app.screen, ConfirmScreen))
            await pilot.press("1", "q")
            await pilot.pause()
            assert isinstance(app.screen, ConfirmScreen) and app.is_running
            assert app.pane == "devices"
            await pilot.press("n")
            await until(pilot, lambda: not isinstance(app.screen, ConfirmScreen))
            await pilot.press("1")
            await until(pilot, lambda: app.pane == "overview")

    asyncio.run(scenario())


def test_the_footer_is_composed_again_only_when_its_keys_change(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Textual's footer made a new row of key widgets at every bindings update, several in
    each pane switch, for the same keys (about half of a switch's 0.8 s of CPU). Now: pane
    switches with the same keys compose nothing, and the footer still shows what changes (the
    filter box's Esc, and after it, not)."""
    composed: list[int] = []
    compose = KeysFooter.compose

    def counted(footer: KeysFooter) -> ComposeResult:
        composed.append(1)
        return compose(footer)

    monkeypatch.setattr(KeysFooter, "compose", counted)

    def keys_shown(app: FrozenTui) -> set[str]:
        return {key.description for key in app.query(FooterKey)}

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: "Quit" in keys_shown(app))
            before = len(composed)
            for pane in (*PANES, *PANES):
                await pilot.press(key_of(pane))
                await shown(pilot, app, pane)
            await pilot.pause()
            assert len(composed) == before, "the same keys composed again"
            assert "Quit" in keys_shown(app) and "Leave filter" not in keys_shown(app)
            await pilot.press("2", "slash")
            await until(pilot, lambda: "Leave filter" in keys_shown(app))
            await pilot.press("escape")
            await until(
                pilot, lambda: "Leave filter" not in keys_shown(app) and "Quit" in keys_shown(app)
            )

    asyncio.run(scenario())
