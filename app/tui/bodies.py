"""The Bodies pane (key 7): the last body's characteristics, the abnormal first and in colour,
and the selected one's trend over the last bodies with its SPC chart's limits and Cp/Cpk
(what it says: app.tui.body_view). The app reads the records and the charts from the database
in a worker thread (app.tui.history) at each refresh, which every event of the service asks
for (a `body` event once a body is stored), and hands them to `BodiesPane.show`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable, Static

from app.inspect.spc import chart_key
from app.tui import body_view

#: the app's table filler (RvisTui._fill: the rows replaced unless unchanged)
Fill = Callable[[str, Sequence[Sequence[Any]]], None]


class BodiesPane(Vertical):
    """The last body on top, its characteristics' table, the selected one's trend under it.
    The selection follows the characteristic (not the row) from one body to the next."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.records: list[dict[str, Any]] = []
        self.charts: dict[str, dict[str, Any]] = {}
        self.keys: list[str] = []  # the table's characteristics, in its order
        self.selected: str | None = None
        self.head = body_view.head_text([])  # the last body's line, as shown

    def compose(self) -> ComposeResult:
        yield Static(self.head, id="body-head")
        # no padding of its own: the rows are padded (an abnormal row one band of colour)
        yield DataTable(id="bodies-table", cursor_type="row", cell_padding=0)
        yield Static("", id="body-trend")

    def on_mount(self) -> None:
        self.query_one("#bodies-table", DataTable).add_columns(
            *(f" {c} " for c in body_view.COLUMNS)
        )

    def show(self, records: list[dict[str, Any]], charts: list[dict[str, Any]], fill: Fill) -> None:
        """The last bodies (oldest first) and the charts; `fill` fills the table."""
        self.records, self.charts = records, {c["key"]: c for c in charts}
        self.head = body_view.head_text(records)
        self.query_one("#body-head", Static).update(self.head)
        last = records[-1] if records else None
        self.keys = [chart_key(v) for v in body_view.ordered(last["values"] if last else [])]
        fill("bodies-table", body_view.value_rows(last))
        table: DataTable[Any] = self.query_one("#bodies-table", DataTable)
        if self.selected in self.keys:  # the same characteristic, wherever its row is now
            table.move_cursor(row=self.keys.index(self.selected))
        elif self.keys:  # none yet, or gone: the one under the cursor
            self.selected = self.keys[min(max(table.cursor_row, 0), len(self.keys) - 1)]
        self._show_trend()

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        table = event.data_table
        if table.id != "bodies-table" or event.cursor_row != table.cursor_row:
            return  # another table's, or stale: the cursor moved on since (`show`)
        if 0 <= event.cursor_row < len(self.keys):
            self.selected = self.keys[event.cursor_row]
            self._show_trend()

    def _show_trend(self) -> None:
        trend = body_view.trend_text(self.selected, self.records, self.charts)
        self.query_one("#body-trend", Static).update(trend if self.records else Text(""))
