"""AQDEF (the Q-DAS ASCII transfer format) `.dfq` files of the bodies' results, for a plant's SPC
system: the part's and each characteristic's description, then each body's values.

One line a key, `Kxxxx/n value` (n: the characteristic's number), lines ended by CR LF, ASCII.
Key meanings from the format's published description (Hexagon's Q-DAS data-format pages,
REFERENCE.md):

    K0100        the number of characteristics in the file
    K1001 K1002  part number, part description (the feature plan's `part`, `description`)
    K1081 K1082  machine number and description: the station
    K2001/n      characteristic number (its key, "H01.X")     K2002/n  its description
    K2004/n 0    variable characteristic                       K2022/n  decimals (3)
    K2008/n      group type: 10 (3-D positional tolerance) on a feature's X, Y and Z; 0 else
    K2101/n      nominal      K2110/n K2111/n  lower and upper limits (absolute)   K2142/n  unit
    K0001/n      the value    K0004/n  its time (DD.MM.YYYY/HH:MM:SS, UTC)
    K0014/n      the part id: the body's id, as the PLC gave it
    K0002/n      attribute: 0 valid; 129 invalid (shown, not calculated): measured inside a
                 suspect interval and not computed again with its correction; 255 placeholder
                 (not shown): not measured, the value written 0
    K0009/n      text: "U95 0.061 mm; conforming" (the format has no field for a value's
                 uncertainty: its U95 and ISO 14253-1 decision ride in the value's text), "not
                 measured: <reason>", and "computed again (evaluation k)" for a body whose values
                 were computed again after a correction, written again as a new file

`dfq_text(plan_part, characteristics, records, station)`: the file's text for the records of
`app.line.body_results.records` (one or several bodies).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

#: K0002 attributes
VALID, INVALID, PLACEHOLDER = 0, 129, 255
DECIMALS = 3


def _clean(text: Any) -> str:
    """A value's text on one line of ASCII (the format's lines are ASCII, CR LF ended)."""
    s = str(text).replace("\r", " ").replace("\n", " ")
    return s.encode("ascii", errors="replace").decode("ascii")


def dfq_time(time_utc: str) -> str:
    """ISO 8601 UTC ("2026-11-29T01:56:13+00:00") -> DD.MM.YYYY/HH:MM:SS."""
    return datetime.fromisoformat(time_utc).astimezone(UTC).strftime("%d.%m.%Y/%H:%M:%S")


def _characteristic_lines(n: int, c: dict[str, Any]) -> list[str]:
    key = f"{c['feature']}.{c['characteristic']}"
    group = 10 if c["characteristic"] in ("X", "Y", "Z") else 0
    return [
        f"K2001/{n} {_clean(key)}",
        f"K2002/{n} {_clean(c['feature'])} {_clean(c['characteristic'])}",
        f"K2004/{n} 0",
        f"K2008/{n} {group}",
        f"K2022/{n} {DECIMALS}",
        f"K2101/{n} {c['nominal_mm']:.{DECIMALS + 3}f}",
        f"K2110/{n} {c['lower_mm']:.{DECIMALS + 3}f}",
        f"K2111/{n} {c['upper_mm']:.{DECIMALS + 3}f}",
        f"K2142/{n} mm",
    ]


def _value_lines(n: int, v: dict[str, Any], rec: dict[str, Any]) -> list[str]:
    if v["measured_mm"] is None:
        value, attribute = 0.0, PLACEHOLDER
        text = f"not measured: {v.get('reason', '')}"
    else:
        value, attribute = float(v["measured_mm"]), INVALID if v.get("suspect") else VALID
        text = f"U95 {v['u95_mm']:.3f} mm; {v['decision']}"
        if v.get("suspect"):
            text += "; suspect"
    if rec.get("evaluation"):
        text += f"; computed again (evaluation {rec['evaluation']})"
    return [
        f"K0001/{n} {value:.6f}",
        f"K0002/{n} {attribute}",
        f"K0004/{n} {dfq_time(rec['time_utc'])}",
        f"K0014/{n} {_clean(rec['body'])}",
        f"K0009/{n} {_clean(text)}",
    ]


def dfq_text(
    part: str, description: str, records: Sequence[dict[str, Any]], station: tuple[str, str]
) -> str:
    """The `.dfq` text (module docstring) of the bodies in `records`, which share one part
    type (their values in the same characteristic order)."""
    if not records:
        raise ValueError("records: at least one body")
    chars = records[0]["values"]
    lines = [
        f"K0100 {len(chars)}",
        f"K1001 {_clean(part)}",
        f"K1002 {_clean(description)}",
        f"K1081 {_clean(station[0])}",
        f"K1082 {_clean(station[1])}",
    ]
    for n, c in enumerate(chars, start=1):
        lines += _characteristic_lines(n, c)
    for rec in records:
        keys = [(v["feature"], v["characteristic"]) for v in rec["values"]]
        if keys != [(c["feature"], c["characteristic"]) for c in chars]:
            raise ValueError(f"body {rec['body']}: another part type's characteristics")
        for n, v in enumerate(rec["values"], start=1):
            lines += _value_lines(n, v, rec)
    return "\r\n".join(lines) + "\r\n"
