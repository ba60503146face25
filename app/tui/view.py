"""What the operator's screens show, as plain text and table rows: pure functions of the
service's status (the socket's `status` reply) and of its history (the database), so that the
Textual widgets only place them. Abnormal values carry a style class; normal ones none
(ISA-101: colour only for the abnormal, and never colour alone: the text says it too).

Without a status reply (no service, or the connection lost) nothing the reply would say is
stated: the values read "unknown" or "-", never a default that looks like a fact (a line "not
running", a heartbeat "lost", "all 0 devices OK"). Likewise the line's facts (running, the PLC
heartbeat, the window) while the service has no answer from its PLC (`line_unknown`). Times
are the service's clock throughout: the history's times are its, and ages are counted on its
`now_utc`. The history screens' rows are app/tui/history_view.py, the alarms'
app/tui/alarm_view.py, the bodies' app/tui/body_view.py.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from app.line.maintenance_state import needed_text, running_text
from app.line.states import accuracy_text, bodies_text

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


def service_now(status: dict[str, Any] | None) -> datetime | None:
    """The service's clock (the status reply's `now_utc`): ages are counted on it, not on the
    terminal's (a simulated line's clock runs ahead of the wall clock)."""
    text = (status or {}).get("now_utc")
    if not isinstance(text, str):
        return None
    try:
        now = datetime.fromisoformat(text)
    except ValueError:
        return None
    return now if now.tzinfo else now.replace(tzinfo=UTC)


def num(value: Any, fmt: str = ".3f", unit: str = "") -> str:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:{fmt}}{unit}"
    return "-"


UNKNOWN = "unknown"


def line_unknown(status: dict[str, Any] | None) -> str | None:
    """Why the line's facts (running, heartbeat, window) are unknown although the service
    answered, or None when they are known: its PLC not opened (unreachable since the start, or
    closed), or its last exchange with the PLC unanswered (the reply's values are then the
    last ones read, or defaults)."""
    plc = ((status or {}).get("devices") or {}).get("plc") or {}
    if plc.get("state") in ("unreachable", "closed"):
        return f"PLC {plc['state']}"
    win = (status or {}).get("window") or {}
    if win.get("plc_answered") is False:
        return "no answer from the PLC"
    return None


def window_text(status: dict[str, Any] | None) -> str:
    """The clamp window, the same words on the status line and the Overview: "window OPEN
    12 s left", "window closed", "window unknown" (no reply, none in it, or no PLC)."""
    win = (status or {}).get("window")
    if not isinstance(win, dict) or "open" not in win or line_unknown(status):
        return f"window {UNKNOWN}"
    if not win.get("open"):
        return "window closed"
    return "window OPEN " + num(win.get("remaining_s"), ".0f", " s left")


def _yes_no(value: Any, yes: str, no: str) -> str:
    """A boolean of the reply in words; "unknown" when the reply does not say."""
    return UNKNOWN if not isinstance(value, bool) else (yes if value else no)


def status_line(
    status: dict[str, Any] | None, connected: bool, detail: str, now: datetime | None = None
) -> str:
    """The one-line summary at the top of every screen (fits 80 columns when normal)."""
    if not connected or status is None:
        return f"DISCONNECTED - {detail}"
    window = window_text(status)
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
    not OK, counters; "unknown" for what there is no reply about (module docstring)."""
    if status is None:
        return "\n".join(
            (
                f"Service   {UNKNOWN} (no reply from the service)",
                f"Line      running {UNKNOWN}, PLC heartbeat {UNKNOWN}, window {UNKNOWN}",
                f"Cell      {UNKNOWN}",
                f"Accuracy  {UNKNOWN}",
                f"Devices   {UNKNOWN}",
                "Counters  -",
                "Knock     -",
            )
        )
    s = status
    win, counts = s.get("window") or {}, s.get("counters") or {}
    no_plc = line_unknown(s)
    heartbeat = UNKNOWN if no_plc else _yes_no(win.get("heartbeat_alive"), "alive", "LOST")
    running = UNKNOWN if no_plc else _yes_no(win.get("line_running"), "yes", "NO")
    temp = s.get("cell_temp_c")
    cell = (
        UNKNOWN
        if "cell_temp_c" not in s
        else ("no cell temperature" if temp is None else num(temp, ".2f", " degC"))
    )
    devices = device_rows(status)
    bad = [f"{d[0]} {d[1]}" for d in devices if d[1] not in ("OK", "OPEN")]
    device_text = ", ".join(bad) or (f"all {len(devices)} OK" if devices else UNKNOWN)
    return "\n".join(
        (
            service_text(s),
            *maintenance_text(s),
            f"Line      running {running}, PLC heartbeat {heartbeat}, {window_text(s)}"
            + (f" ({no_plc})" if no_plc else ""),
            f"Cell      {cell}",
            f"Accuracy  {accuracy_text(s) if 'accuracy' in s else UNKNOWN}",
            f"Devices   {device_text}",
            "Counters  " + (", ".join(f"{k} {v}" for k, v in counts.items()) or "-"),
            "Knock     " + knock_text(s),
        )
    )


def service_text(status: dict[str, Any]) -> str:
    """The Overview's service line: its state and step; held for maintenance (the `maintenance`
    alarm in force), what moved and the procedure that fits instead of a bare FAULT."""
    need = (status.get("maintenance") or {}).get("needed")
    if need:
        return f"Service   MAINTENANCE NEEDED ({status.get('state', UNKNOWN)}): {needed_text(need)}"
    return f"Service   {status.get('state', UNKNOWN)}   step: {status.get('step') or '-'}"


def maintenance_text(status: dict[str, Any]) -> tuple[str, ...]:
    """The Overview's line of a maintenance procedure recorded running (none otherwise)."""
    running = (status.get("maintenance") or {}).get("running")
    return (f"Maint.    IN MAINTENANCE: {running_text(running)}",) if running else ()


def maintenance_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(id, event (`axis 3`), from, to, by, versions, the workspace validation's RMS before
    and after) per maintenance procedure, as app.tui.history gives them; a procedure not
    handed back yet reads RUNNING."""

    def rms(doc: Any) -> str:
        return num((doc or {}).get("validation_rmse_mm"), ".3f")

    return [
        (
            str(r.get("id")),
            " ".join(str(v) for v in (r.get("event"), r.get("axis")) if v is not None),
            time_text(r.get("start_utc")),
            time_text(r.get("end_utc")) or str(r.get("status") or "").upper(),
            str(r.get("who") or ""),
            f"{r.get('version_before') or '-'} -> {r.get('version_after') or '-'}",
            f"{rms(r.get('before'))} -> {rms(r.get('after'))}",
        )
        for r in rows
    ]


def knock_text(status: dict[str, Any]) -> str:
    """The jump in hand (the one estimator's, app.line.jumps) or the last suspect interval, in
    one line ('none' when neither)."""
    jump = status.get("jump")
    if jump and not jump.get("closed"):
        what = jump.get("what") or "finding what moved"
        state = "CORRECTED" if jump.get("corrected_version") else "CORRECTING"
        return f"{state}: {jump.get('text') or 'a jump'}: {what}"
    intervals = status.get("suspect_intervals") or []
    if not intervals:
        return "none"
    last = intervals[-1]
    end = "OPEN" if last.get("end_utc") is None else time_text(last.get("end_utc"))[11:]
    bodies = last.get("bodies") or []
    return (
        f"last suspect interval {time_text(last.get('start_utc'))[5:]} - {end},"
        f" {num(last.get('size_mm'), '.3f', ' mm')} ({last.get('group') or '?'})"
        + (f", bodies {bodies_text(bodies)}" if bodies else "")
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


def device_rows(status: dict[str, Any] | None) -> list[tuple[str, str, str]]:
    """(family, state, URL) per device; its last error is in `device_errors` (whole)."""
    devices = (status or {}).get("devices") or {}
    return [
        (family, str(d.get("state", "?")).upper(), str(d.get("url", "")))
        for family, d in devices.items()
    ]


def device_errors(status: dict[str, Any] | None) -> str:
    """The last error the service saw from each device, with its time, whole (wrapped to the
    screen, never cut: at 80 columns a table column would cut it); kept after a reset."""
    if status is None or "devices" not in status:
        return f"devices' last errors {UNKNOWN}"
    failed = {f: d for f, d in (status.get("devices") or {}).items() if d.get("last_error")}
    width = max(map(len, failed), default=0)
    lines = [
        f"{family:<{width}}  {time_text(d.get('last_error_utc')) or '-'}  {d['last_error']}"
        for family, d in failed.items()
    ]
    if not lines:
        return "no device error seen"
    return "\n".join(["Last error of each device (kept after a reset):", *lines])


def time_text(utc: Any) -> str:
    """'2026-11-23 09:12:40' of an ISO UTC time ('' when none)."""
    return str(utc or "")[:19].replace("T", " ")


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
