"""What the operator's history screens show (app/tui/view.py's rules): the rows of the
measurements, in-line calibrations, parameter versions, suspect intervals and the event log,
and the words for each kind of event."""

from __future__ import annotations

import json
from typing import Any

from app.line.states import bodies_text
from app.tui.view import PRIORITY_TEXT, num, time_text


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


def suspect_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(id, from, to, size, bodies, what) per suspect interval, as app.tui.history gives them;
    bodies: how many, the first and the last (suspect_detail lists them all)."""
    return [
        (
            str(r.get("id")),
            time_text(r.get("start_utc")),
            time_text(r.get("end_utc")) or "OPEN",
            num(r.get("size_mm"), ".3f"),
            bodies_text(r.get("bodies") or []),
            str(r.get("text") or ""),
        )
        for r in rows
    ]


def suspect_detail(r: dict[str, Any] | None) -> str:
    """The selected suspect interval's bodies, every one (the table shows the first and last)."""
    if r is None:
        return "no suspect interval selected"
    bodies = r.get("bodies") or []
    head = f"#{r.get('id')} from {time_text(r.get('start_utc'))}"
    head += f" to {time_text(r.get('end_utc')) or 'now (OPEN)'}"
    if not bodies:
        return f"{head}: no bodies known (the PLC's body id is read with [line] plc_body_id)"
    return f"{head}: {len(bodies)} bodies: {', '.join(map(str, bodies))}"


def log_rows(rows: list[dict[str, Any]]) -> list[tuple[str, ...]]:
    """(time, kind, what happened) per event of the service: one readable line each."""
    return [
        (
            time_text(e.get("utc")),
            str(e.get("kind", "")),
            event_text(e.get("kind"), e.get("detail")),
        )
        for e in rows
    ]


def event_text(kind: Any, detail: Any) -> str:
    """An event's data (the JSON the service stored) as a line for people."""
    try:
        d = json.loads(detail) if isinstance(detail, str) else dict(detail or {})
    except (ValueError, TypeError):
        return str(detail or "")
    if not isinstance(d, dict):
        return str(d)
    g = d.get
    texts = {
        "window": lambda: (
            f"window {g('window')}: slots {g('slots')}, measured {g('measured')},"
            f" rejected {g('rejected')}"
            + (" OVERRUN" if g("overrun") else "")
            + (f", withdrawn ({g('withdrawn_reason')})" if g("withdrawn") else "")
            + (f", {g('note')}" if g("note") else "")
        ),
        "measurement": lambda: (
            f"{g('target')} slot {g('slot')} {g('status')},"
            f" residual {num(g('residual_mm'), '.4f', ' mm')}"
            + (f" ({g('reason')})" if g("reason") else "")
        ),
        "alarm": lambda: (
            f"{PRIORITY_TEXT.get(str(g('priority')), g('priority'))} {g('code')}: {g('message')}"
        ),
        "alarm_cleared": lambda: f"{g('code')} cleared",
        "calibration": lambda: (
            f"calibration {g('id')} {g('status')}: RMS"
            f" {num(g('rms_mm'), '.4f', ' mm')}, held-out {num(g('holdout_rms_mm'), '.4f')} vs"
            f" {num(g('current_holdout_rms_mm'), '.4f', ' mm')} in force" + _failures(g("failures"))
        ),
        "parameters_applied": lambda: (
            f"version {g('version')} in force ({g('source')},"
            f" calibration {g('calibration_id') or '-'})"
        ),
        "recalibration_started": lambda: (
            f"identification on {g('n')} measurements ({g('first_id')}..{g('last_id')})"
        ),
        "state": lambda: f"{g('from')} -> {g('to')}",
        "device_retry": lambda: (
            f"try {g('attempts')}: "
            + "; ".join(f"{k} unreachable ({v})" for k, v in dict(g("unreachable") or {}).items())
        ),
        "operator": lambda: f"{g('cmd')} by uid {g('uid')}: {'ok' if g('ok') else 'refused'}",
        "step_attribution": lambda: (
            f"{g('text')}" + (" -> corrected" if g("passed") else "") + _failures(g("failures"))
        ),
        "suspect_interval": lambda: (
            f"suspect interval {g('id')} {g('state')}: from"
            f" {time_text(g('start_utc'))}"
            + (f" to {time_text(g('end_utc'))}" if g("end_utc") else "")
            + f", {num(g('size_mm'), '.3f', ' mm')}"
            + (f" ({g('group')})" if g("group") else "")
            + (f", bodies {bodies_text(g('bodies') or [])}" if g("bodies") else "")
        ),
    }
    make = texts.get(str(kind))
    if make is not None:
        return make()
    return ", ".join(f"{k} {v}" for k, v in d.items())


def _failures(failures: Any) -> str:
    return "; " + "; ".join(str(f) for f in failures) if failures else ""
