"""Issue 49 item 3, the operator's view of the bodies (the Bodies pane, key 7): what it says
(app.tui.body_view) on frozen records, what it reads from a real database
(app.tui.history: the last bodies and the SPC charts, read-only), and the pane at 80x24: the
last body's NOK and its nonconforming row on screen with the trend's limits and Cp/Cpk."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from rich.text import Text
from textual.widgets import DataTable, Static

from app.inspect.spc import BASELINE_N, IndividualsChart
from app.line.body_results import capability
from app.line.store import Store
from app.tui.bodies import BodiesPane
from app.tui.body_view import (
    COLUMNS,
    DECISION_STYLE,
    NOK_STYLE,
    POINT_STYLE,
    head_text,
    plot,
    tolerance_text,
    trend_text,
    value_rows,
)
from app.tui.history import HistoryReader
from tests.tui.frozen import BODIES, HISTORY, FrozenTui
from tests.tui.helpers import until
from tests.tui.test_screens import screen_lines

CHARTS = {c["key"]: c for c in HISTORY["charts"]}


def styles_of(cell: Text) -> set[str]:
    return {str(span.style) for span in cell.spans}


def test_the_abnormal_rows_come_first_each_in_its_colour_and_words() -> None:
    rows = value_rows(BODIES[-1])
    first = [(str(r[0]).strip(), str(r[-1]).strip()) for r in rows[:3]]
    assert first == [("H01.Z", "NONCONFORMING"), ("P01.N", "NOT MEASURED"), ("H02.X", "UNDECIDED")]
    for row, decision in zip(rows, ("nonconforming", "not measured", "undecided"), strict=False):
        assert all(styles_of(c) == {DECISION_STYLE[decision]} for c in row)  # the whole row
    conforming = rows[3:]
    assert conforming and all(str(r[-1]).strip() == "conforming" for r in conforming)
    assert all(not c.spans and not c.style for r in conforming for c in r)  # grey: ISA-101
    # the plan's order within a group; every column padded to one width
    assert [str(r[0]).strip() for r in conforming][:3] == ["H01.X", "H01.Y", "H01.D"]
    assert len({tuple(c.cell_len for c in r) for r in rows}) == 1 and len(rows[0]) == len(COLUMNS)
    h01z = [str(c).strip() for c in rows[0]]
    assert h01z[1:6] == ["150.000", "150.709", "+0.709", "±0.50", "0.060"]
    assert [str(c).strip() for c in rows[1]][2:4] == ["-", "-"]  # no number where none was


def test_the_head_says_the_body_its_result_and_counts() -> None:
    head = head_text(BODIES)
    assert head.plain.startswith("Body 100415  2026-11-23 09:29:10   NOK ")
    assert "1 nonconforming, 1 undecided, 1 not measured of 13" in head.plain
    assert "last 25 bodies: 4 NOK" in head.plain
    (nok,) = [s for s in head.spans if s.style == NOK_STYLE]
    assert head.plain[nok.start : nok.end].strip() == "NOK"
    ok = head_text(BODIES[:3])
    assert " OK " in ok.plain and not ok.spans  # OK is not coloured
    suspect = head_text([{**BODIES[-1], "suspect_interval": 2}])
    assert "SUSPECT: measured inside suspect interval 2" in suspect.plain
    assert head_text([]).plain.startswith("no body measured yet")


def test_tolerances_as_deviations() -> None:
    value = {"nominal_mm": 10.0, "lower_mm": 9.8, "upper_mm": 10.3}
    assert tolerance_text(value) == "-0.20/+0.30"
    assert tolerance_text({**value, "lower_mm": 9.7}) == "±0.30"


def test_the_trend_has_the_charts_limits_and_the_capability_over_the_bodies() -> None:
    text = trend_text("H01.Z", BODIES, CHARTS).plain.splitlines()
    chart, nominal = CHARTS["H01.Z"], 150.0
    (cap,) = [c for c in capability(BODIES) if (c["feature"], c["characteristic"]) == ("H01", "Z")]
    assert text[0] == (
        f"H01.Z last 25 (dev mm): CL {chart['centre_mm'] - nominal:+.3f}"
        f" LCL {chart['lcl_mm'] - nominal:+.3f} UCL {chart['ucl_mm'] - nominal:+.3f}"
        f"  Cp {cap['cp']:.2f} Cpk {cap['cpk']:.2f} (n 25)"
    )
    lines = text[1:]
    assert len(lines) == 5 and all(len(line) == len(lines[0]) for line in lines)
    names = [line[:7].strip() for line in lines]
    assert [n for n in names if n] == ["UCL", "CL", "LCL"]
    # the shifted bodies (the last 5) above the upper limit, the baseline's between the limits
    ucl, lcl = names.index("UCL"), names.index("LCL")
    column = [[line[9 + 2 * k] for line in lines].index("●") for k in range(25)]
    assert all(c < ucl for c in column[20:]) and all(ucl < c < lcl for c in column[:20])
    # not measured in the last body: said with the reason
    p01 = trend_text("P01.N", BODIES, CHARTS).plain
    assert "not measured in body 100415: plane: too few points on the sheet" in p01


def test_a_chart_without_its_baseline_and_a_point_in_its_decisions_colour() -> None:
    young = {"H01.Z": {"key": "H01.Z", "centre_mm": None, "baseline_n": 3}}
    assert "chart limits after 20 values (3 so far)" in trend_text("H01.Z", BODIES[:3], young)
    (line,) = [t for t in plot([(0.7, "nonconforming"), (0.0, "conforming")], None, 1)]
    assert [s.style for s in line.spans] == [POINT_STYLE["nonconforming"]]
    assert plot([], None) == []


def _value(name: str, measured: float | None, decision: str = "conforming") -> dict[str, Any]:
    return {
        "feature": "H01", "characteristic": name, "kind": "position", "nominal_mm": 10.0,
        "lower_mm": 9.5, "upper_mm": 10.5, "measured_mm": measured,
        "u95_mm": None if measured is None else 0.06, "decision": decision,
        "reason": "" if measured is not None else "edge_points: 3",
    }  # fmt: skip


def test_the_history_reads_the_last_bodies_and_the_services_charts(tmp_path: Path) -> None:
    """Through the store as the service writes it: the last 25 bodies oldest first with their
    newest evaluation, the charts from the first bodies (as the service's replay), read once."""
    store = Store(tmp_path / "rvis.db")
    xs = [10.0 + 0.01 * ((7 * k) % 11) for k in range(45)]
    for k, x in enumerate(xs):
        values = [_value("X", x), _value("Y", None if k % 2 else x, "not measured")]
        summary = {"ok": 1, "n_nok": 0, "n_undecided": 0, "n_not_measured": 0}
        evaluation = {"t": 100.0 + k, "params_version": 1, "statement_u95_mm": 0.08,
                      "reason": "measured", **summary}  # fmt: skip
        body = {"t": 100.0 + k, "body_id": 500 + k, "part": "P", "window": k}
        store.add_body(body, evaluation, values, [])
    store.close()
    history = HistoryReader(tmp_path / "rvis.db")
    bodies = history.bodies(25)
    assert [b["body"] for b in bodies] == list(range(520, 545))
    assert [v["measured_mm"] for b in bodies for v in b["values"][:1]] == xs[20:]
    charts = {c["key"]: c for c in history.charts()}
    expected = IndividualsChart("H01.X")
    for k, x in enumerate(xs[:BASELINE_N]):
        expected.add(x, k)
    assert charts["H01.X"]["centre_mm"] == expected.centre
    assert (charts["H01.X"]["lcl_mm"], charts["H01.X"]["ucl_mm"]) == expected.limits_mm
    # Y measured in every other body: its baseline is complete within the first 40 bodies too
    assert charts["H01.Y"]["baseline_n"] == BASELINE_N
    assert history.charts() is history._charts[1]  # the first bodies unchanged: not read again
    assert HistoryReader(tmp_path / "none.db").bodies(25) == []


def test_at_80x24_the_nok_body_its_row_and_the_trend_are_on_screen() -> None:
    async def scenario() -> list[str]:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("7")
            await until(pilot, lambda: app.pane == "bodies" and not app.refreshing, 10.0)
            await pilot.pause(0.2)
            return screen_lines(app.export_screenshot())

    lines = asyncio.run(scenario())
    assert len(lines) <= 24 and all(len(line) <= 80 for line in lines)
    text = "\n".join(lines)
    assert "7 Body" in lines[2] and "1 Overview" in lines[2]  # every tab fits
    assert "Body 100415" in text and "NOK" in text
    for shown in ("H01.Z", "NONCONFORMING", "NOT MEASURED", "UNDECIDED", "UCL", "LCL", "Cpk"):
        assert shown in text, shown
    assert lines[-1].startswith("q Quit")


def test_the_selection_stays_on_its_characteristic_from_one_body_to_the_next() -> None:
    """H02.X selected while undecided (third row); in the next body it conforms and its row
    moves down: the cursor and the trend follow it."""
    after = [*BODIES[1:], {**BODIES[-2], "body": BODIES[-1]["body"] + 1}]

    async def scenario() -> None:
        app = FrozenTui()
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("7")
            pane = app.query_one(BodiesPane)
            table: DataTable[Any] = app.query_one("#bodies-table", DataTable)
            await until(pilot, lambda: table.row_count > 0 and pane.selected == "H01.Z", 10.0)
            await pilot.press("down", "down")
            await until(pilot, lambda: pane.selected == "H02.X", 10.0)
            app.frozen_history = {**HISTORY, "bodies": after}
            app.refresh_all()
            await until(pilot, lambda: pane.head.plain.startswith("Body 100416 "), 10.0)
            await until(pilot, lambda: table.cursor_row == pane.keys.index("H02.X"), 10.0)
            assert table.cursor_row > 2 and pane.selected == "H02.X"
            trend = str(app.query_one("#body-trend", Static).render())
            assert trend.startswith("H02.X last 25")

    asyncio.run(scenario())
