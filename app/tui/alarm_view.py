"""What the operator's alarm screen shows (app/tui/view.py's rules; ISA-18.2 states): the
alarms' rows, one alarm in words, who acknowledged it, and the priority's cell."""

from __future__ import annotations

import pwd
from typing import Any

from rich.text import Text

from app.tui.view import ACTIVE_ALARM_STATES, PRIORITY_TEXT, time_text


def user_name(uid: Any) -> str:
    """Who a uid is on this machine ("alice"; "uid 1001" without an account; "-")."""
    if not isinstance(uid, int) or isinstance(uid, bool):
        return "-"
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"uid {uid}"


def alarm_state(a: dict[str, Any]) -> str:
    """ISA-18.2's state: RAISED (unacknowledged), ACKED, SHELVED, CLEARED (acknowledged), or
    CLEARED UNACK (returned to normal without an acknowledgement: it can still be acked)."""
    state = str(a.get("state", "")).upper()
    if state == "CLEARED" and a.get("t_acked") is None and "t_acked" in a:
        return "CLEARED UNACK"
    return state


def acked_text(a: dict[str, Any]) -> str:
    """Who acknowledged the alarm and when ("-": nobody yet)."""
    if a.get("t_acked") is None:
        return "-"
    who = "OPC UA" if a.get("acked_uid") is None else user_name(a.get("acked_uid"))
    return f"{who} {time_text(a.get('acked_utc'))[11:16]}".strip()


def alarm_rows(alarms: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """(id, priority, state, raised, acked by, text, shelved until/reason) per alarm, newest
    first."""
    rows = []
    for a in sorted(alarms, key=lambda a: a.get("id", 0), reverse=True):
        shelved = a.get("shelved_until_utc") or ""
        if shelved:
            shelved = f"until {shelved[11:16]}: {a.get('shelve_reason', '')}"
        rows.append(
            (
                str(a.get("id", "")),
                priority_cell(str(a.get("priority", "")), str(a.get("state", ""))),
                alarm_state(a),
                time_text(a.get("raised_utc")),
                acked_text(a),
                str(a.get("text", "")),
                shelved,
            )
        )
    return rows


def alarm_detail(a: dict[str, Any] | None) -> str:
    """The selected alarm whole (the table cuts its text at the screen's width)."""
    if a is None:
        return "no alarm selected"
    prio = PRIORITY_TEXT.get(str(a.get("priority")), str(a.get("priority", "")))
    lines = [
        f"#{a.get('id')} {prio} {a.get('code', '')}, {alarm_state(a)};"
        f" raised {time_text(a.get('raised_utc'))}"
    ]
    if a.get("t_acked") is not None:
        who = "OPC UA" if a.get("acked_uid") is None else user_name(a.get("acked_uid"))
        uid = "" if a.get("acked_uid") is None else f" (uid {a.get('acked_uid')})"
        lines[0] += f"; acknowledged by {who}{uid} at {time_text(a.get('acked_utc'))}"
    if a.get("cleared_utc"):
        lines[0] += f"; cleared {time_text(a.get('cleared_utc'))}"
    if a.get("shelved_until_utc"):
        lines[0] += (
            f"; shelved until {time_text(a.get('shelved_until_utc'))}:"
            f" {a.get('shelve_reason') or ''}"
        )
    lines.append(str(a.get("text", "")))
    return "\n".join(lines)


PRIORITY_STYLE = {
    "urgent": "bold #ffffff on #d70000",
    "high": "bold #ffffff on #d70000",
    "medium": "bold #000000 on #ffaf00",
    "low": "#000000 on #5f87af",
}


def priority_cell(priority: str, state: str) -> Text:
    """The priority as text, coloured only while the alarm is active (raised or acked)."""
    style = PRIORITY_STYLE.get(priority, "") if state in ACTIVE_ALARM_STATES else ""
    return Text(f" {PRIORITY_TEXT.get(priority, priority)} ", style=style)
