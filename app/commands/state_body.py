"""`rvis state body BODY [--json]`: how sure the measurement of one body is, from the state
database, read-only (the service may run): the clamp window(s) it was clamped in with the
parameters version in force then and the U95 the cell stated for a point measured then
(`[service] accuracy_limit_mm` is what it vouches for), the suspect intervals it falls in (as
`rvis state suspects` lists their bodies: measured with a calibration wrong by about the
interval's size), and, when the cell measured the body's features, each value with its U95 and
decision (as `rvis results show`). Light: SQLite and the standard library.

    {"body": 100012, "windows": [{"t_utc", "params_version", "u95_mm"}],
     "suspect": true, "suspect_intervals": [...as rvis state suspects], "measured": null | {...}}
"""

from __future__ import annotations

import bisect
from typing import Any

from app.errors import InputError


def body_answer(state: Any, body: str, now_t: float) -> dict[str, Any]:
    """The answer for `body` (its id as the PLC gave it) in the state directory `state`;
    InputError (field BODY) when no window clamped it and the cell never measured it."""
    from app.line.body_results import records
    from app.line.states import suspect_json, utc_text
    from app.line.store import Store

    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state.root)
    store = Store.read_only(state.db)
    try:
        windows = store.windows_of(body)
        measured = records(store, None, body, now_t)
        applied = [(float(a["t"]), int(a["version"])) for a in store.applied()]
        intervals = [
            suspect_json(r)
            for r in store.suspects()
            if any(str(b) == str(body) for b in r.get("bodies") or [])
        ]
    finally:
        store.close()
    if not windows and not measured:
        raise InputError(f"no body {body!r} clamped or measured here", field="BODY")
    record = measured[-1] if measured else None
    measured_suspect = record is not None and record["suspect_interval"] is not None
    return {
        "body": windows[0]["body_id"] if windows else record and record["body"],
        "windows": [
            {
                "t_utc": utc_text(float(w["t"])),
                "params_version": _in_force(applied, float(w["t"])),
                "u95_mm": w.get("u95_mm"),
            }
            for w in windows
        ],
        "suspect": bool(intervals) or measured_suspect,
        "suspect_intervals": intervals,
        "measured": record,
    }


def _in_force(applied: list[tuple[float, int]], t: float) -> int | None:
    """The parameters version in force at `t` (applied rows in time order; None before any)."""
    k = bisect.bisect_right([a for a, _ in applied], t) - 1
    return applied[k][1] if k >= 0 else None


def body_text(doc: dict[str, Any]) -> str:
    """The answer in words: each window, each interval, the values."""
    from app.line.body_results import show_text

    lines = []
    for w in doc["windows"]:
        stated = (
            "no U95 stated for it"
            if w["u95_mm"] is None
            else f"the cell stated U95 {w['u95_mm']:.3f} mm for a point measured then"
        )
        lines.append(
            f"body {doc['body']}: clamped in the window of {w['t_utc']}, parameters version"
            f" {w['params_version'] if w['params_version'] is not None else '-'}; {stated}"
        )
    for r in doc["suspect_intervals"]:
        size = "size unknown" if r["size_mm"] is None else f"about {r['size_mm']:.3f} mm off"
        span = f"{r['start_utc']} .. {r['end_utc'] or 'open'}"
        lines.append(
            f"SUSPECT: in suspect interval #{r['id']} ({span}, {size}):"
            f" {r['text'] or r.get('group') or ''}; measure it again or flag it"
        )
    if doc["measured"] is not None:
        lines.append(show_text(doc["measured"]))
    if not doc["suspect"]:
        lines.append("not in a suspect interval")
    return "\n".join(lines)
