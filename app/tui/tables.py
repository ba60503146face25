"""A table of the operator's terminal filled with rows (every pane's, app.tui.app)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rich.cells import cell_len
from rich.text import Text
from textual.widgets import DataTable


def fill(table: DataTable[Any], rows: Sequence[Sequence[Any]]) -> None:
    """Replace a table's rows, keeping the cursor on the same row index."""
    cursor = table.cursor_row
    table.clear()
    table.add_rows(rows)
    # the columns' widths for these rows at once: the table measures new rows when it is
    # next idle, which in a full test suite left a pane (shown meanwhile) with its header's
    # widths and every cell cut (seen for the calibrations, measurements and log panes)
    for column, cells in zip(table.ordered_columns, zip(*rows, strict=False), strict=False):
        if column.auto_width:
            width = max(c.cell_len if isinstance(c, Text) else cell_len(str(c)) for c in cells)
            column.content_width = max(column.content_width, width)
    table.refresh(layout=True)
    if rows:
        table.move_cursor(row=min(cursor, len(rows) - 1))
