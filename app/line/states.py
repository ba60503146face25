"""The in-line service's vocabulary, shared by the service and its collaborators (the
operator's commands, the step handling, the status reply) and by the commands that read its
database (`rvis status`, `rvis state suspects`): its states, the alarms that hold the cell in
FAULT, the UTC text of the service's clock, an alarm and a suspect interval as JSON. Light: no
numerics."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any


class State(StrEnum):
    """The service's state (DESIGN.md section 6)."""

    STARTING = "starting"
    IDLE = "idle"
    MEASURING = "measuring"
    PAUSED = "paused"
    FAULT = "fault"
    STOPPED = "stopped"


class AlarmCode(StrEnum):
    """Every alarm code the service can raise, with its condition class (`kind`): "process"
    (the measured cell: the robot's accuracy, the sensor) or "system" (devices, storage,
    software). The one list of codes: the service raises, clears and looks up alarms by these
    members, never by a bare string (tests/line/test_alarm_codes.py scans app/ for that)."""

    kind: str

    def __new__(cls, code: str, kind: str) -> AlarmCode:
        member = str.__new__(cls, code)
        member._value_ = code
        member.kind = kind
        return member

    DEVICE_FAULT = "device_fault", "system"
    #: at start; retried, cleared when it answers (not reset)
    DEVICE_UNREACHABLE = "device_unreachable", "system"
    ROBOT_NOT_HOME = "robot_not_home", "system"
    INTERNAL_ERROR = "internal_error", "system"
    STATE_STORAGE = "state_storage", "system"
    PARAMS_REBUILT = "params_rebuilt", "system"
    PLC_HEARTBEAT = "plc_heartbeat", "system"
    TEMPERATURE = "temperature", "system"
    LOW_DISK = "low_disk", "system"
    DRIFT_STEP = "drift_step", "process"
    SENSOR = "sensor", "process"
    #: a schedule's view rejected again and again: skipped, re-plan
    VIEW_LOST = "view_lost", "process"
    #: a change beyond a knock: held in FAULT until `rvis maintain` hands the cell back
    MAINTENANCE = "maintenance", "process"
    #: the results directory cannot be written: the bodies' files wait in the database
    RESULTS_DIR = "results_dir", "system"
    #: a characteristic's individuals chart signalled: the process's or maybe the gauge's
    SPC = "spc", "process"
    #: windows in a row the cell could not vouch for its U95 within the plant's limit
    ACCURACY = "accuracy", "process"


#: codes an older rvis raised that nothing raises now (the drift charts' `drift`): an active one
#: in a state directory is cleared at start
RETIRED_CODES = ("drift",)


#: alarms that hold the cell in FAULT until a reset
FAULT_CODES = (
    AlarmCode.DEVICE_FAULT,
    AlarmCode.ROBOT_NOT_HOME,
    AlarmCode.INTERNAL_ERROR,
    AlarmCode.STATE_STORAGE,
    AlarmCode.MAINTENANCE,
)

#: every alarm code the service can raise -> its condition class (AlarmCode, read as a
#: mapping): OPC UA makes one condition of each from the start (app.line.opcua.alarms);
#: tests/line/test_alarm_codes.py checks the service raises no other.
ALARM_CODES: dict[str, str] = {code.value: code.kind for code in AlarmCode}


def utc_text(t: float) -> str:
    """ISO 8601 UTC of a clock time (seconds since the epoch)."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="seconds")


def alarm_detail(a: Mapping[str, Any]) -> dict[str, Any] | None:
    """An alarm's structured fields beside its text (the store's JSON `detail`, or a dict
    already), None without any or when unreadable."""
    detail = a.get("detail")
    if isinstance(detail, str):
        try:
            detail = json.loads(detail)
        except ValueError:
            return None
    return dict(detail) if isinstance(detail, dict) else None


def alarm_status(a: Mapping[str, Any]) -> dict[str, Any]:
    """An alarm as the status reply carries it (the message also as `text`; `detail`: its
    structured fields, when it has any)."""
    out = {k: a[k] for k in ("id", "code", "priority", "message", "state")}
    out["text"] = a["message"]
    out["raised_utc"] = utc_text(a["t_raised"])
    detail = alarm_detail(a)
    if detail is not None:
        out["detail"] = detail
    return out


def alarm_event(a: Mapping[str, Any], state: str, **more: Any) -> dict[str, Any]:
    """An alarm's change as the events carry it (`alarm`, `alarm_acked`, `alarm_shelved`,
    `alarm_unshelved`, `alarm_cleared`): the alarm's fields with its state after the change,
    so that a consumer (the OPC UA server) applies each change in order without a query."""
    return {**alarm_status(a), "state": state, **more}


def suspect_json(row: Mapping[str, Any]) -> dict[str, Any]:
    """A suspect interval as events, the status reply and `rvis state suspects` carry it;
    `bodies`: the ids of the bodies clamped in the windows inside it, in order (an open one's
    up to now; app.line.store.suspect_rows; empty when the PLC's body id is not read)."""

    def utc(t: Any) -> str | None:
        return None if t is None else utc_text(float(t))

    return {
        "id": row.get("id"),
        "state": "open" if row.get("t_end") is None else "closed",
        "t_start": row.get("t_start"),
        "t_end": row.get("t_end"),
        "start_utc": utc(row.get("t_start")),
        "end_utc": utc(row.get("t_end")),
        "last_good_id": row.get("last_good_id"),
        "onset_id": row.get("onset_id"),
        "params_version": row.get("params_version"),
        "size_mm": row.get("size_mm"),
        "group": row.get("group_name"),
        "text": row.get("text"),
        "end_reason": row.get("end_reason"),
        "end_version": row.get("end_version"),
        "calibration_id": row.get("calibration_id"),
        "bodies": list(row.get("bodies") or ()),
        # its bodies computed again with the correction: how many, the decisions that changed,
        # and those it could not correct (measured before the step's first moved measurement:
        # they may precede it, measure them again); None: not (yet) computed again
        "reevaluated": row.get("reevaluated"),
        "decisions_changed": row.get("decisions_changed"),
        "not_reevaluated": row.get("not_reevaluated"),
    }


def bodies_text(bodies: Sequence[Any]) -> str:
    """A suspect interval's bodies in a few characters: how many, the first and the last."""
    if not bodies:
        return "none"
    if len(bodies) == 1:
        return f"1: {bodies[0]}"
    return f"{len(bodies)}: {bodies[0]} .. {bodies[-1]}"


def accuracy_text(status: dict[str, Any]) -> str:
    """The U95 the cell states for a point measured now, against its limit, in words; with no
    service running, the last one it stated (`window_utc`: the window it was stated for); on a
    cell not commissioned, that it is not and when its first calibration comes."""
    first = status.get("uncommissioned")  # the running service's: when the first calibration
    # comes (app.line.uncommissioned)
    return _stated(status) + (f"; not commissioned: {first['text']}" if first else "")


def _stated(status: dict[str, Any]) -> str:
    acc = status.get("accuracy")
    if not acc:
        return "not stated yet (no window measured)"
    u95, limit = acc.get("u95_mm"), acc.get("limit_mm")
    last = ""
    if status.get("state") == "not running":
        when = acc.get("window_utc")
        last = f" (the last window's{f', {when}' if when else ''}; the service is not running)"
    if u95 is None:
        return f"U95 unknown (no evidence yet): cannot vouch for {limit:.3f} mm{last}"
    if limit is None:  # stored by a service that did not save its statement
        return f"U95 {u95:.3f} mm{last}"
    word = "vouched for" if acc.get("vouched") else "CANNOT VOUCH"
    n, basis = acc.get("n"), acc.get("basis")
    return f"U95 {u95:.3f} mm ({n} measurements, {basis}), limit {limit:.3f} mm: {word}{last}"


#: what lifts the hold on automatic applies after a rollback in auto mode (app.line.operator)
HOLD_LIFT = "automatic applies wait for an engineer's resume or approve (rvis ctl resume)"


def hold_text(hold: Mapping[str, Any] | None, mode: str) -> str:
    """How calibrations that pass their gates are applied now, in words (the status reply's
    `mode` and `auto_hold`)."""
    if hold is None:
        return "auto (applied at once)" if mode == "auto" else f"{mode} (an engineer approves)"
    return (
        f"auto, HELD since {hold['since_utc']} by the rollback to version {hold['version']}:"
        f" {HOLD_LIFT}"
    )
