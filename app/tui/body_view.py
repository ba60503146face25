"""What the Bodies pane says (the operator's view of the bodies measured, issue 49): pure
functions of the last bodies' records (app.line.body_results.records, as `rvis results` reads
them, oldest first) and of the service's SPC charts (app.tui.history.HistoryReader.charts).

- the last body at the top: its id, time, OK or NOK, how many characteristics are
  nonconforming, undecided, not measured; suspect or computed again when it is;
- its characteristics, the abnormal first (nonconforming, not measured, undecided, then
  conforming; each group in the plan's order): nominal, measured, deviation, tolerance, U95 and
  the decision (ISO 14253-1 with the value's U95, app.inspect.values) in words and, when it is
  abnormal, in colour (ISA-101: a conforming value is grey like the rest of the screen);
- the selected characteristic's trend over the last `TREND_N` bodies as deviations from its
  nominal, with the centre line and control limits of the service's individuals chart
  (app.inspect.spc: from the characteristic's first 20 values), and Cp/Cpk over those bodies
  (app.line.body_results.capability: the values measured and not suspect).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from rich.text import Text

from app.inspect.spc import BASELINE_N, chart_key
from app.line.body_results import capability
from app.tui.alarm_view import PRIORITY_STYLE
from app.tui.view import num, time_text

#: the bodies the trend and the capability look back over
TREND_N = 25
#: the trend's plot: lines, and columns a body
PLOT_LINES = 5
PLOT_STEP = 2
COLUMNS = ("charact.", "nominal mm", "measured mm", "dev mm", "tol mm", "U95 mm", "decision")
#: a point of the trend's plot in its decision's colour (the glyph's, on the grey)
POINT_STYLE = {"nonconforming": "bold #ff5f5f", "undecided": "bold #ffaf00"}
DECISION_TEXT = {
    "conforming": "conforming",
    "nonconforming": "NONCONFORMING",
    "undecided": "UNDECIDED",
    "not measured": "NOT MEASURED",
}
#: colour for the abnormal only (ISA-101), the decision written as well: red as a high
#: alarm's, amber as a medium one's; a value not measured in the colour of what is not known
#: (the status line's DISCONNECTED)
DECISION_STYLE = {
    "nonconforming": PRIORITY_STYLE["high"],
    "undecided": PRIORITY_STYLE["medium"],
    "not measured": "bold #ffffff on #5f005f",
}
#: the order of the rows: the abnormal first
DECISION_ORDER = {"nonconforming": 0, "not measured": 1, "undecided": 2, "conforming": 3}
NOK_STYLE = PRIORITY_STYLE["high"]
SUSPECT_STYLE = PRIORITY_STYLE["medium"]


def deviation_mm(value: dict[str, Any]) -> float | None:
    measured = value.get("measured_mm")
    return None if measured is None else float(measured) - float(value["nominal_mm"])


def tolerance_text(value: dict[str, Any]) -> str:
    """The tolerance as deviations: "±0.50", or "-0.20/+0.30" when not symmetric."""
    lo = float(value["lower_mm"]) - float(value["nominal_mm"])
    hi = float(value["upper_mm"]) - float(value["nominal_mm"])
    if math.isclose(-lo, hi, abs_tol=5e-4):
        return f"±{hi:.2f}"
    return f"{lo:+.2f}/{hi:+.2f}"


def head_text(records: Sequence[dict[str, Any]]) -> Text:
    """The last body's summary, and how many of the last bodies were NOK."""
    if not records:
        return Text(
            "no body measured yet (the service measures a clamped body by its feature plan)"
        )
    r = records[-1]
    out = Text(f"Body {r['body']}  {time_text(r['time_utc'])}  ")
    out.append(" OK " if r["ok"] else " NOK ", style="" if r["ok"] else NOK_STYLE)
    n = len(r["values"])
    out.append(
        f"  {r['n_nok']} nonconforming, {r['n_undecided']} undecided,"
        f" {r['n_not_measured']} not measured of {n}"
    )
    nok = sum(not b["ok"] for b in records)
    out.append(f"; last {len(records)} bodies: {nok} NOK; parameters v{r['params_version']}")
    if r.get("suspect_interval") is not None:
        out.append("  ")
        suspect = f" SUSPECT: measured inside suspect interval {r['suspect_interval']} "
        out.append(suspect, style=SUSPECT_STYLE)
    if r.get("reevaluated"):
        out.append(f"; computed again after a correction (evaluation {r['evaluation']})")
    return out


def ordered(values: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The values, the abnormal first (DECISION_ORDER), each group in the plan's order."""
    return sorted(values, key=lambda v: DECISION_ORDER.get(str(v["decision"]), 0))


def value_rows(record: dict[str, Any] | None) -> list[tuple[Text, ...]]:
    """A row per characteristic of the body (COLUMNS), in `ordered` order, each cell padded
    to its column (the table has no padding of its own): an abnormal row is one band of its
    decision's colour."""
    values = ordered(record["values"] if record else [])
    cells = [
        (
            chart_key(v),
            num(v["nominal_mm"]),
            num(v.get("measured_mm")),
            num(deviation_mm(v), "+.3f"),
            tolerance_text(v),
            num(v.get("u95_mm")),
            DECISION_TEXT.get(str(v["decision"]), str(v["decision"])),
        )
        for v in values
    ]
    widths = [max(len(c) for c in column) for column in zip(COLUMNS, *cells, strict=True)]
    rows = []
    for v, row in zip(values, cells, strict=True):
        style = DECISION_STYLE.get(str(v["decision"]), "")
        padded = [
            f" {c.ljust(w) if k in (0, len(row) - 1) else c.rjust(w)} "
            for k, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        rows.append(tuple(Text.styled(c, style) if style else Text(c) for c in padded))
    return rows


def trend_text(
    key: str | None, records: Sequence[dict[str, Any]], charts: dict[str, dict[str, Any]]
) -> Text:
    """The characteristic's trend over the records (module docstring): a caption with the
    chart's centre and limits and the capability, then the plot (PLOT_LINES lines)."""
    if key is None or not records:
        return Text("select a characteristic: its trend over the last bodies shows here")
    points = [_point(key, r) for r in records]
    known = [v for v in (_value(key, r) for r in records) if v is not None]
    if not known:
        return Text(f"{key}: not in the last bodies")
    nominal = float(known[-1]["nominal_mm"])
    chart = charts.get(key) or {}
    limits = None
    if chart.get("centre_mm") is not None:
        limits = tuple(float(chart[k]) - nominal for k in ("lcl_mm", "centre_mm", "ucl_mm"))
    out = Text(f"{key} last {len(records)} (dev mm): ")
    if limits is None:
        n = chart.get("baseline_n", 0)
        out.append(f"chart limits after {BASELINE_N} values ({n} so far)")
    else:
        out.append(f"CL {limits[1]:+.3f} LCL {limits[0]:+.3f} UCL {limits[2]:+.3f}")
    cap = next((c for c in capability(records) if chart_key(c) == key), None)
    if cap is not None:
        out.append(f"  Cp {num(cap['cp'], '.2f')} Cpk {num(cap['cpk'], '.2f')} (n {cap['n']})")
    last = _value(key, records[-1])
    if last is not None and last.get("measured_mm") is None:
        out.append(f"\nnot measured in body {records[-1]['body']}: {last.get('reason') or '-'}")
    for line in plot(points, limits):
        out.append("\n")
        out.append_text(line)
    return out


def _value(key: str, record: dict[str, Any]) -> dict[str, Any] | None:
    return next((v for v in record["values"] if chart_key(v) == key), None)


def _point(key: str, record: dict[str, Any]) -> tuple[float | None, str]:
    """(deviation, decision) of the characteristic in a body: (None, ...) not measured."""
    v = _value(key, record)
    if v is None:
        return None, "not measured"
    return deviation_mm(v), str(v["decision"])


def plot(
    points: Sequence[tuple[float | None, str]],
    limits: tuple[float, ...] | None,
    lines: int = PLOT_LINES,
) -> list[Text]:
    """The points (deviation, decision; oldest first, PLOT_STEP columns each) on `lines` lines,
    the chart's (LCL, CL, UCL) as lines named at the left; a point in its decision's colour, a
    value not measured as a gap."""
    ys = [y for y, _ in points if y is not None] + list(limits or ())
    if not ys:
        return []
    lo, hi = min(ys), max(ys)
    if hi - lo < 1e-6:
        lo, hi = lo - 0.001, hi + 0.001

    def line_of(y: float) -> int:
        return round((hi - y) / (hi - lo) * (lines - 1))

    width = PLOT_STEP * len(points)
    cells: list[list[tuple[str, str]]] = [[(" ", "")] * width for _ in range(lines)]
    names = [""] * lines
    if limits is not None:
        for name, y, char in zip(("LCL", "CL", "UCL"), limits, "─·─", strict=True):
            k = line_of(y)
            cells[k] = [(char, "")] * width
            names[k] = f"{names[k]}/{name}" if names[k] else name
    for i, (dev, decision) in enumerate(points):
        if dev is not None:
            cells[line_of(dev)][PLOT_STEP * i] = ("●", POINT_STYLE.get(decision, ""))
    out = []
    for name, row in zip(names, cells, strict=True):
        text = Text(f"{name[:7]:>7} {'┤' if name else '│'}")
        for char, style in row:
            text.append(char, style=style or None)
        out.append(text)
    return out
