"""The keys of the operator's terminal (the keys' table in docs/tui.md): which key does what,
and from which focus.

The screen keys (1-7 switch panes, q quits) are priority bindings: they act whatever widget has
the focus (a table, the tabs, a scrolled pane), except while the cursor is in a filter box,
where letters and digits are typed (a sphere filter needs "P2"); there Escape leaves the box
(Enter applies the filter and leaves it too) and the keys act again. Ctrl+Q quits from anywhere.
While a dialog asks, only its own keys answer (app.tui.app.RvisTui.check_action)."""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any, ClassVar

from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.message import Message
from textual.screen import Screen
from textual.widgets import Footer, Input

PANES = ("overview", "measurements", "calibrations", "alarms", "devices", "log", "bodies")
#: the widget a pane's key gives the focus to: its table (up/down select a row at once; the
#: filter box is reached with / or Tab)
PANE_FOCUS = {
    "overview": "suspects-table",
    "measurements": "measurements-table",
    "calibrations": "versions-table",
    "alarms": "alarms-table",
    "devices": "devices-table",
    "log": "log-table",
    "bodies": "bodies-table",
}
#: the panes with a filter box, and its id
PANE_FILTER = {"measurements": "sphere-filter", "log": "log-filter"}
#: the actions that the screen keys run (never while a dialog asks)
SCREEN_ACTIONS = ("show", "quit")

BINDINGS: list[BindingType] = [
    *(
        Binding(str(k + 1), f"show('{p}')", p.title(), show=False, priority=True)
        for k, p in enumerate(PANES)
    ),
    # the footer shows them in this order; at 80 columns all of them fit (short words)
    Binding("q", "quit", "Quit", priority=True),
    Binding("p", "pause_resume", "Pause"),
    Binding("r", "reset", "Reset"),
    Binding("c", "recalibrate", "Recal"),
    Binding("a", "approve", "Approve"),
    Binding("x", "reject", "Reject"),
    Binding("b", "rollback", "Rollback"),
    Binding("k", "ack", "Ack"),
    Binding("s", "shelve", "Shelve"),
    # not in the footer (no room at 80 columns): the filter box's placeholder says it
    Binding("slash", "filter", "Filter", show=False),
]


class FilterInput(Input):
    """A pane's filter box: what is typed filters the pane's table; Enter applies it now,
    Escape or Enter give the focus back to the table (the screen keys act again)."""

    BINDINGS: ClassVar[list[BindingType]] = [Binding("escape", "leave", "Leave filter")]

    class Left(Message):
        """The operator left the filter box with Escape (the app focuses the table)."""

        def __init__(self, box: FilterInput) -> None:
            super().__init__()
            self.box = box

    def action_leave(self) -> None:
        self.post_message(self.Left(self))


def _keys_shown(screen: Screen[Any]) -> tuple[Hashable, ...]:
    """What the footer shows of a screen's keys: each shown binding's key, action, words, group
    and whether it is enabled."""
    return tuple(
        (b.key, b.action, b.description, enabled, tooltip, id(b.group))
        for (_, b, enabled, tooltip) in screen.active_bindings.values()
        if b.show
    )


class KeysFooter(Footer):
    """The footer of the keys, composed again only when the keys it shows change. Textual's
    Footer composes a new row of key widgets at every bindings update, several times in a pane
    switch (the focus leaves, the tabs change, the table takes it): about 0.8 s of CPU a switch,
    most of it in these widgets' styles, for the same keys."""

    _shown: tuple[Hashable, ...] | None = None

    def compose(self) -> ComposeResult:
        if self._bindings_ready:
            self._shown = _keys_shown(self.screen)
        yield from super().compose()

    def bindings_changed(self, screen: Screen[Any]) -> None:
        shown = _keys_shown(screen)
        if self._bindings_ready and screen is self.screen and shown == self._shown:
            return
        super().bindings_changed(screen)
        if screen.app.app_focus and self.is_attached and screen is self.screen:
            self._shown = shown  # composed after the next refresh (or newer, by then)
