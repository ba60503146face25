"""What the operator's screens show, as plain text and table rows: pure functions of the
service's status (the socket's `status` reply) and of its history (the database), so that the
Textual widgets only place them. Abnormal values carry a style class; normal ones none
(ISA-101: colour only for the abnormal, and never colour alone: the text says it too).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from rich.text import Text

PRIORITY_CLASS = {
    "urgent": "alarm-high",
    "high": "alarm-high",
    "medium": "alarm-medium",
    "low": "alarm-low",
}
PRIORITY_TEXT = {"urgent": "URGENT", "high": "HIGH", "medium": "MED", "low": "LOW"}
ACTIVE_ALARM_STATES = ("raised", "acked")


def age_text(utc: str | None, now: datetime | None = None) -> str:
    """'3 h 12 min ago' from an ISO UTC time; '-' when unknown."""
    if not utc:
        return "-"
    try:
        then = datetime.fromisoformat(utc)
    except ValueError:
        return utc
    if then.tzinfo is None:
        then = then.replace(tzinfo=UTC)
    s = max(0, int(((now or datetime.now(UTC)) - then).total_seconds()))
    if s < 60:
        return f"{s} s ago"
    if s < 3600:
        return f"{s // 60} min ago"
    return f"{s // 3600} h {s % 3600 // 60} min ago"


def num(value: Any, fmt: str = ".3f", unit: str = "") -> str:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:{fmt}}{unit}"
    return "-"


def status_line(
    status: dict[str, Any] | None, connected: bool, detail: str, now: datetime | None = None
) -> str:
    """The one-line summary at the top of every screen (fits 80 columns when normal)."""
    if not connected or status is None:
        return f"DISCONNECTED - {detail}"
    win = status.get("window") or {}
    window = (
        f"window {num(win.get('remaining_s'), '.0f', ' s')}" if win.get("open") else ("no window")
    )
    cal = status.get("calibration") or {}
    version = cal.get("version")
    calib = (
        "no calibration"
        if version is None
        else (
            f"cal v{version} {age_text(cal.get('applied_utc'), now).removesuffix(' ago')} old, "
            f"{num(cal.get('rms_mm'), '.3f', ' mm')}"
        )
    )
    return f"{status.get('state', '?')} ({status.get('step') or '-'}) | {window} | {calib}"


def overview_text(status: dict[str, Any] | None) -> str:
    """The Overview's lines: service, line (running, PLC heartbeat, window), devices that are
    not OK, counters."""
    s = status or {}
    win, counts = s.get("window") or {}, s.get("counters") or {}
    window = "closed"
    if win.get("open"):
        window = "OPEN " + num(win.get("remaining_s"), ".0f", " s left")
    heartbeat = "alive" if win.get("heartbeat_alive") else "LOST"
    running = "yes" if win.get("line_running") else "NO"
    temp = s.get("cell_temp_c")
    cell = "no cell temperature" if temp is None else num(temp, ".2f", " degC")
    devices = device_rows(status)
    bad = [f"{d[0]} {d[2]}" for d in devices if d[2] not in ("OK", "OPEN")]
    return "\n".join(
        (
            f"Service   {s.get('state', '-')}   step: {s.get('step', '-')}",
            f"Line      running {running}, PLC heartbeat {heartbeat}, window {window}",
            f"Cell      {cell}",
            "Devices   " + (", ".join(bad) if bad else f"all {len(devices)} OK"),
            "Counters  " + ", ".join(f"{k} {v}" for k, v in counts.items()),
        )
    )


def active_alarms(status: dict[str, Any] | None) -> list[dict[str, Any]]:
    alarms = (status or {}).get("alarms") or []
    order = {"urgent": 0, "high": 1, "medium": 2, "low": 3}
    active = [a for a in alarms if a.get("state") in ACTIVE_ALARM_STATES]
    return sorted(active, key=lambda a: (order.get(a.get("priority", "low"), 4), a.get("id", 0)))


def banner(status: dict[str, Any] | None) -> tuple[str, str]:
    """(text, style class) of the alarm banner: the most urgent active alarm, or ('', '')."""
    alarms = active_alarms(status)
    if not alarms:
        return "", ""
    top = alarms[0]
    prio = top.get("priority", "low")
    more = f"  (+{len(alarms) - 1} more)" if len(alarms) > 1 else ""
    acked = " [acknowledged]" if top.get("state") == "acked" else ""
    text = f"ALARM {PRIORITY_TEXT.get(prio, prio)}: {top.get('text', '')}{acked}{more}"
    return text, PRIORITY_CLASS.get(prio, "alarm-low")


def device_rows(status: dict[str, Any] | None) -> list[tuple[str, str, str, str, str]]:
    """(family, URL, state, time of its last error, last error) per device: the last error the
    service saw from that device, also after the fault was reset."""
    devices = (status or {}).get("devices") or {}
    return [
        (
            family,
            str(d.get("url", "")),
            str(d.get("state", "?")).upper(),
            time_text(d.get("last_error_utc")),
            str(d.get("last_error") or ""),
        )
        for family, d in devices.items()
    ]


def time_text(utc: Any) -> str:
    """'2026-11-23 09:12:40' of an ISO UTC time ('' when none)."""
    return str(utc or "")[:19].replace("T", " ")


def measurement_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(id, time, sphere, status, residual, note) per measurement."""
    return [
        (
            str(m.get("id")),
            time_text(m.get("utc")),
            str(m.get("sphere", "")),
            str(m.get("status", "")).upper(),
            num(m.get("residual_mm"), ".4f"),
            str(m.get("reason") or ""),
        )
        for m in rows
    ]


def calibration_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(id, time, status, version, RMS, gates) per in-line calibration."""
    return [
        (
            str(c.get("id")),
            time_text(c.get("utc")),
            str(c.get("status", "")).upper(),
            str(c.get("version") or "-"),
            num(c.get("rms_mm"), ".4f"),
            str(c.get("gates") or ""),
        )
        for c in rows
    ]


def version_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(version, in force since, source, calibration) per parameters version put in force."""
    return [
        (
            str(a.get("version")),
            time_text(a.get("utc")),
            str(a.get("source", "")),
            str(a.get("calibration_id") or "-"),
        )
        for a in rows
    ]


def log_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(time, kind, detail) per event of the service."""
    return [
        (time_text(e.get("utc")), str(e.get("kind", "")), str(e.get("detail", ""))) for e in rows
    ]


def alarm_rows(alarms: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """(id, priority, state, raised, text, shelved until/reason) per alarm, newest first."""
    rows = []
    for a in sorted(alarms, key=lambda a: a.get("id", 0), reverse=True):
        shelved = a.get("shelved_until_utc") or ""
        if shelved:
            shelved = f"until {shelved[11:16]}: {a.get('shelve_reason', '')}"
        rows.append(
            (
                str(a.get("id", "")),
                priority_cell(str(a.get("priority", "")), str(a.get("state", ""))),
                str(a.get("state", "")).upper(),
                time_text(a.get("raised_utc")),
                str(a.get("text", "")),
                shelved,
            )
        )
    return rows


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


def parameter_diff_rows(pending: dict[str, Any]) -> list[tuple[str, ...]]:
    """(name, unit, current, pending, change, std, change/std) of a pending calibration."""
    rows: list[tuple[str, ...]] = []
    for p in pending.get("parameters", []):
        cur, new, std = p.get("current"), p.get("value"), p.get("std")
        change = (
            new - cur if isinstance(new, float | int) and isinstance(cur, float | int) else None
        )
        ratio = abs(change) / std if change is not None and std else None
        rows.append(
            (
                str(p.get("name", "")),
                str(p.get("unit", "")),
                num(cur, ".5f"),
                num(new, ".5f"),
                num(change, "+.5f"),
                num(std, ".5f"),
                num(ratio, ".1f"),
            )
        )
    return rows
