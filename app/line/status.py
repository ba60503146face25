"""The status reply of the service (`rvis status`, the TUI, OPC UA): pure functions of the
service as its collaborators see it (app.line.host.LineHost)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from app.line.host import LineHost
from app.line.maintenance_state import RECORDS_IN_STATUS, maintenance_json, procedures_text
from app.line.opcua import FEED_NAME
from app.line.states import AlarmCode, alarm_status, suspect_json, utc_text
from app.line.states import alarm_event as alarm_event  # where app.line.window_loop reads it
from app.line.store import StorageError
from app.line.uncommissioned import uncommissioned

SUSPECTS_IN_STATUS = 5  # the status reply's last suspect intervals


def status_reply(svc: LineHost) -> dict[str, Any]:
    """The status reply; answered even when the state storage fails (what could not be
    read is left out and `storage_error` says why)."""
    try:
        return _status(svc)
    except StorageError as exc:
        return {
            "state": svc.state.value,
            "paused": svc.decision.paused,
            "params_version": svc.version,
            "counters": dict(svc.decision.counters),
            "alarms": [alarm_status(a) for a in svc.fault.unstored_alarms],
            "step": step_text(svc),
            # the U95 of a point measured now, vouched for or not (app.line.accuracy)
            "accuracy": None if svc.accuracy.now is None else svc.accuracy.now.to_json(),
            "storage_error": str(exc),
            **_opcua_status(svc),
        }


def step_text(svc: LineHost, maintenance: Mapping[str, Any] | None = None) -> str:
    """What the service is doing, in a few words (the TUI's status line); `maintenance`: the
    reply's (app.line.maintenance_state), whose `maintenance` alarm holds the cell."""
    need = (maintenance or {}).get("needed")
    if need and svc.state.name == "FAULT":
        return f"held for maintenance: {procedures_text(need)}"
    if svc.recalibrator.busy:
        return "recalibrating"
    if svc.station.unreachable and svc.fault.retry is not None:
        names = ", ".join(svc.station.unreachable)
        return f"waiting for {names} (unreachable): next try {svc.fault.retry['next_utc']}"
    steps = {
        "MEASURING": "measuring in the window",
        "IDLE": "waiting for a window",
        "PAUSED": "paused by the operator",
        "FAULT": "stopped on a fault, reset needed",
    }
    return steps.get(svc.state.name, svc.state.value.lower())


def device_of(exc: BaseException, devices: Mapping[str, object]) -> str | None:
    """The family of the device that raised `exc` (the stamp a device's public method puts on
    its errors, drivers.errors; or its cause's), when it is one of `devices`; else None."""
    seen: BaseException | None = exc
    while seen is not None:
        family = getattr(seen, "family", None)
        if isinstance(family, str) and family in devices:
            return family
        seen = seen.__cause__
    return None


def _status(svc: LineHost) -> dict[str, Any]:
    w = svc.watch
    alarms = svc.store.active_alarms() + svc.fault.unstored_alarms
    maintenance = maintenance_json(
        alarms, svc.store.maintenance(last=RECORDS_IN_STATUS), svc.paths.root
    )
    return {
        "state": svc.state.value,
        "paused": svc.decision.paused,
        "params_version": svc.version,
        "pending_calibration": svc.decision.pending_calibration,
        "recalibrating": svc.recalibrator.busy,
        "mode": svc.settings.recalib.mode,
        # a rollback in auto mode: applies wait for an engineer
        "auto_hold": svc.decision.auto_hold,
        "counters": dict(svc.decision.counters),
        "measurements": svc.store.counts(),
        "schedule": {"position": svc.store.schedule_position()[0], "slots": len(svc.schedule)},
        "plc": None
        if w.inputs is None
        else {
            "window_open": w.inputs.window_open,
            "line_running": w.inputs.line_running,
            "heartbeat_alive": w.alive,
        },
        "window": _window_status(svc),
        "calibration": _calibration_status(svc),
        "alarms": [alarm_status(a) for a in alarms],
        "cell_temp_c": svc.cell_temp_c,
        # per sphere, its measurements in the one estimator's window (app.line.estimate)
        "spheres": svc.sphere_residuals(),
        "step": step_text(svc, maintenance),
        # the U95 of a point measured now, vouched for or not (app.line.accuracy)
        "accuracy": None if svc.accuracy.now is None else svc.accuracy.now.to_json(),
        "uncommissioned": uncommissioned(svc),  # no calibration of the cell yet: when it comes
        # the `maintenance` alarm in force, a procedure running, the last done
        "maintenance": maintenance,
        "devices": _device_status(svc),
        "device_retry": svc.fault.retry,
        "pending": _pending_status(svc),
        "now_utc": utc_text(svc.clock.time()),  # the service's clock (sim: ahead)
        # a jump the one estimator found, in hand (app.line.jumps): a copy (the loop changes it)
        "jump": None if svc.decision.episode is None else dict(svc.decision.episode),
        "suspect_intervals": [
            suspect_json(r) for r in svc.store.suspects(last=SUSPECTS_IN_STATUS)
        ],  # the last ones, oldest first; the open one has no end yet
        **_opcua_status(svc),
    }


def _opcua_status(svc: LineHost) -> dict[str, Any]:
    """`opcua`: the alarm events the OPC UA server's feed lost (app.line.opcua.feed), when
    one feeds; else nothing."""
    lost = svc.bus.lost(FEED_NAME)
    return {} if lost is None else {"opcua": {"events_dropped": lost}}


def _device_status(svc: LineHost) -> dict[str, dict[str, Any]]:
    """Per device family: the URL it was opened with, its state (unreachable: not opened yet
    since the start, retried; closed; fault: the device of the fault in force, or every device
    when that one is unknown; the PLC without heartbeat; ok), and the last error the service saw
    from it with its time (kept after a reset)."""
    faulted = bool(svc.store.active_alarms(code=AlarmCode.DEVICE_FAULT))
    out = {}
    for family, device in svc.station.devices().items():
        state = "ok"
        if family in svc.station.unreachable:
            state = "unreachable"
        elif not device.is_open:
            state = "closed"
        elif faulted and svc.fault.family in (None, family):
            state = "fault"
        elif family == "plc" and svc.watch.lost:
            state = "no heartbeat"
        last = svc.fault.device_errors.get(family, {})
        out[family] = {
            "url": svc.station.urls.get(family, ""),
            "state": state,
            "last_error": last.get("error"),
            "last_error_utc": last.get("utc"),
        }
    return out


def _calibration_status(svc: LineHost) -> dict[str, Any]:
    """The parameters in force: version, when applied (UTC), the fit's RMS if identified."""
    applied = [a for a in svc.store.applied() if a["version"] == svc.version]
    last = applied[-1] if applied else None
    rms = None
    if last is not None and last["calibration_id"] is not None:
        cal = svc.store.calibration(int(last["calibration_id"]))
        rms = None if cal is None else cal["rms_mm"]
    return {
        "version": svc.version,
        "pending": svc.decision.pending_calibration,
        "applied_utc": None if last is None else utc_text(last["t"]),
        "rms_mm": rms,
    }


def _pending_status(svc: LineHost) -> dict[str, Any] | None:
    """The calibration waiting for approval: fit, gates and each parameter's change."""
    cal_id = svc.decision.pending_calibration
    cal = None if cal_id is None else svc.store.calibration(cal_id)
    if cal is None:
        return None
    current = dict(zip(svc.model.names, (float(v) for v in svc.x), strict=True))
    params = (cal.get("document") or {}).get("parameters", [])
    return {
        "id": cal_id,
        "rms_mm": cal["rms_mm"],
        "holdout_rms_mm": cal["holdout_rms_mm"],
        "current_holdout_rms_mm": cal["current_holdout_rms_mm"],
        "gates": {"passed": not cal["gates"], "failures": list(cal["gates"])},
        "parameters": [
            {
                "name": p["name"],
                "unit": p.get("unit", ""),
                "current": current.get(p["name"]),
                "value": p.get("value"),
                "std": p.get("std"),
            }
            for p in params
            if p.get("identified", True)
        ],
    }


def _window_status(svc: LineHost) -> dict[str, Any]:
    """The line as the TUI shows it: window open and the time left, line, heartbeat, and
    whether the PLC answered the last exchange (if not, the others are not the line's now)."""
    w = svc.watch
    i = w.inputs
    is_open = bool(i is not None and i.window_open)
    return {
        "open": is_open,
        "remaining_s": w.remaining_s() if is_open and w.opened_t is not None else None,
        "line_running": bool(i is not None and i.line_running),
        "heartbeat_alive": w.alive,
        "plc_answered": w.answered,
    }
