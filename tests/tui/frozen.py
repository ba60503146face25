"""A RvisTui with frozen data (no service, no database, a fixed clock): what the screenshot
tests and docs/tui/*.svg show. The status and history are shaped exactly as the service's
`status` reply and app.tui.history return them. FAULT_STATUS: the same line in a fault, its
PLC unreachable since the start (the service's words for it, app/line/startup.py)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.inspect.spc import BASELINE_N, IndividualsChart, add_values
from app.tui.app import PANE_HISTORY, RvisTui

NOW = datetime(2026, 11, 23, 9, 30, tzinfo=UTC)

STATUS: dict[str, Any] = {
    "ok": True,
    "state": "idle",
    "step": "waiting for a window",
    "window": {
        "open": False,
        "remaining_s": None,
        "line_running": True,
        "heartbeat_alive": True,
        "plc_answered": True,
    },
    "calibration": {
        "version": 3,
        "pending": 4,
        "applied_utc": "2026-11-23T06:18:00+00:00",
        "rms_mm": 0.0412,
    },
    "devices": {
        "plc": {"url": "plc+modbus://10.0.0.5:502", "state": "ok", "last_error": None},
        "robot": {
            "url": "rmi://10.0.0.7:16001",
            "state": "ok",
            "last_error": "DeviceFault: SRVO-050 Collision Detect Alarm (G:1 A:2)",
            "last_error_utc": "2026-11-23T04:12:09+00:00",
        },
        "camera": {"url": "aravis://Basler-22C1", "state": "ok", "last_error": None},
        "galvo": {"url": "scpi:///dev/ttyUSB0", "state": "ok", "last_error": None},
    },
    "pending": {
        "id": 4,
        "rms_mm": 0.0398,
        "holdout_rms_mm": 0.0441,
        "gates": {"passed": True, "failures": []},
        "parameters": [
            {"name": "tx_ps", "unit": "mm", "current": 1.2031, "value": 1.2312, "std": 0.004},
            {"name": "alpha1", "unit": "rad", "current": 1.5708, "value": 1.57091, "std": 2e-5},
            {"name": "a2", "unit": "mm", "current": 870.012, "value": 870.046, "std": 0.011},
        ],
    },
    "alarms": [
        {
            "id": 7,
            "code": "drift",
            "priority": "medium",
            "state": "raised",
            "message": "drift of P2 (cusum 0.203 > 0.187 mm): recalibration brought forward",
            "text": "drift of P2 (cusum 0.203 > 0.187 mm): recalibration brought forward",
            "raised_utc": "2026-11-23T09:12:40+00:00",
        }
    ],
    "cell_temp_c": 27.91,
    "accuracy": {
        "u95_mm": 0.0934,
        "n": 24,
        "basis": "estimator",
        "limit_mm": 0.15,
        "vouched": True,
    },
    "counters": {"windows": 412, "overruns": 0, "withdrawn": 3},
    "jump": None,
    "suspect_intervals": [
        {
            "id": 2,
            "start_utc": "2026-11-23T07:41:12+00:00",
            "end_utc": "2026-11-23T07:43:30+00:00",
            "size_mm": 0.226,
            "group": "sensor",
            "text": "sensor mount moved 0.66 mm / 0.229 deg (0.22 mm at the measured spheres)",
            "bodies": [100412, 100413, 100414],
        }
    ],
}


def _measurements() -> list[dict[str, Any]]:
    rows = []
    for k in range(24):
        sphere = f"P{k % 4 + 1}"
        r = 0.03 + 0.002 * (k % 5) + (0.02 if sphere == "P2" and k > 12 else 0.0)
        rows.append(
            {
                "id": 1000 - k,
                "utc": f"2026-11-23T09:{29 - k:02d}:00+00:00",
                "sphere": sphere,
                "status": "rejected" if k == 5 else "ok",
                "residual_mm": r,
                "reason": "too few points" if k == 5 else "",
            }
        )
    return rows


#: the frozen part: (feature, characteristic, nominal, tolerance +-) of a few characteristics
PART = (
    ("H01", "X", 1500.0, 0.5), ("H01", "Y", -300.0, 0.5), ("H01", "Z", 150.0, 0.5),
    ("H01", "D", 10.0, 0.2), ("H02", "X", 1620.0, 0.5), ("H02", "Y", -410.0, 0.5),
    ("H02", "Z", 180.0, 0.5), ("S01", "X", 1710.5, 0.5), ("S01", "Y", -250.0, 0.5),
    ("S01", "Z", 210.0, 0.5), ("S01", "W", 8.0, 0.2), ("S01", "L", 20.0, 0.2),
    ("P01", "N", 0.0, 0.7),
)  # fmt: skip
FIRST_BODY = 100391


def _decision(dev: float, tol: float, u95: float) -> str:
    if abs(dev) <= tol - u95:
        return "conforming"
    return "nonconforming" if abs(dev) > tol + u95 else "undecided"


def _bodies(n: int = 25) -> list[dict[str, Any]]:
    """The last n bodies as app.line.body_results.records gives them (oldest first): H01.Z
    shifted by 0.6 mm from the 21st on (a process shift: the last body NOK), H02.X near its
    limit (undecided) and P01 not measured in the last body."""
    out = []
    for k in range(n):
        values = []
        for j, (feature, name, nominal, tol) in enumerate(PART):
            size = name in "DWL"
            dev = (0.004 if size else 0.09) * math.sin(1.7 * k + 2.3 * j) + 0.01 * (j % 3)
            dev += 0.6 if (feature, name) == ("H01", "Z") and k >= 20 else 0.0
            dev += 0.48 if (feature, name) == ("H02", "X") and k == n - 1 else 0.0
            u95 = 0.01 if size else 0.06
            values.append({
                "feature": feature, "characteristic": name, "nominal_mm": nominal,
                "measured_mm": nominal + dev, "lower_mm": nominal - tol,
                "upper_mm": nominal + tol, "u95_mm": u95, "decision": _decision(dev, tol, u95),
                "suspect": False, "reason": "",
            })  # fmt: skip
        if k == n - 1:
            values[-1].update(measured_mm=None, u95_mm=None, decision="not measured",
                              reason="plane: too few points on the sheet")  # fmt: skip
        decisions = [v["decision"] for v in values]
        nok, und, nm = (decisions.count(d) for d in ("nonconforming", "undecided", "not measured"))
        out.append({
            "body": FIRST_BODY + k, "time_utc": f"2026-11-23T09:{5 + k:02d}:10+00:00",
            "part": "SIM-BIW-01", "evaluation": 0, "params_version": 3,
            "statement_u95_mm": 0.085, "ok": nok == 0 and nm == 0, "n_nok": nok,
            "n_undecided": und, "n_not_measured": nm, "suspect_interval": None,
            "reevaluated": False, "values": values,
        })  # fmt: skip
    return out


def _charts(bodies: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The SPC charts as app.tui.history.HistoryReader.charts gives them: from the first 20
    bodies here."""
    charts: dict[str, IndividualsChart] = {}
    for b in bodies[:BASELINE_N]:
        add_values(charts, b["body"], b["values"])
    return [
        {"key": key, "centre_mm": c.centre, "sigma_mm": c.sigma, "lcl_mm": c.limits_mm[0],
         "ucl_mm": c.limits_mm[1], "baseline_n": len(c.baseline)}
        for key, c in charts.items()
    ]  # fmt: skip


BODIES = _bodies()
HISTORY: dict[str, list[dict[str, Any]]] = {
    "bodies": BODIES,
    "charts": _charts(BODIES),
    "measurements": _measurements(),
    "recent": _measurements(),
    "calibrations": [
        {
            "id": 4,
            "utc": "2026-11-23T09:20:00",
            "status": "pending",
            "version": None,
            "rms_mm": 0.0398,
            "gates": "all gates passed",
        },
        {
            "id": 3,
            "utc": "2026-11-23T06:18:00",
            "status": "applied",
            "version": 3,
            "rms_mm": 0.0412,
            "gates": "all gates passed",
        },
        {
            "id": 2,
            "utc": "2026-11-23T03:02:00",
            "status": "rejected",
            "version": None,
            "rms_mm": 0.0731,
            "gates": "held-out RMS 0.081 > 0.060 mm",
        },
    ],
    "applied": [
        {"version": 3, "utc": "2026-11-23T06:18:00", "source": "approved", "calibration_id": 3},
        {
            "version": 2,
            "utc": "2026-11-22T22:40:00",
            "source": "maintenance",
            "calibration_id": None,
        },
        {"version": 1, "utc": "2026-11-22T08:00:00", "source": "initial", "calibration_id": None},
    ],
    "maintenance": [  # as app.tui.history reads them (newest first)
        {
            "id": 1,
            "t_start": 1795384800.0,
            "t_end": 1795387200.0,
            "start_utc": "2026-11-22T22:00:00+00:00",
            "end_utc": "2026-11-22T22:40:00+00:00",
            "event": "axis",
            "axis": 3,
            "who": "anna",
            "folder": "maintenance/0001-axis3",
            "status": "done",
            "version_before": 1,
            "version_after": 2,
            "before": {"version": 1, "validation_rmse_mm": 0.061},
            "after": {"version": 2, "validation_rmse_mm": 0.064},
        },
    ],
    "alarms": [  # as app.tui.history reads them (every column of the alarms table)
        {**STATUS["alarms"][0], "t_acked": None, "acked_uid": None, "shelved_until_utc": ""},
        {
            "id": 6,
            "code": "plc_heartbeat",
            "priority": "high",
            "state": "cleared",  # and never acknowledged (ISA-18.2: returned to normal, unack)
            "raised_utc": "2026-11-23T04:01:00",
            "cleared_utc": "2026-11-23T04:03:10",
            "t_acked": None,
            "acked_uid": None,
            "text": "PLC heartbeat lost: no window is used until it returns",
            "shelved_until_utc": "",
        },
        {
            "id": 5,
            "code": "device_fault",
            "priority": "urgent",
            "state": "cleared",
            "raised_utc": "2026-11-23T04:12:09",
            "acked_utc": "2026-11-23T04:15:30",
            "cleared_utc": "2026-11-23T04:20:00",
            "t_acked": 1795407330.0,
            "acked_uid": 0,
            "text": "robot: DeviceFault: SRVO-050 Collision Detect Alarm (G:1 A:2): the robot is"
            " stopped, the PLC fault bit set; nothing moves until an operator resets the cell"
            " after removing the cause",
            "shelved_until_utc": "",
        },
    ],
    "suspects": [
        {
            "id": 2,
            "start_utc": "2026-11-23T07:41:12",
            "end_utc": "2026-11-23T07:43:30",
            "size_mm": 0.226,
            "text": "sensor mount moved 0.66 mm / 0.229 deg (0.22 mm at the measured spheres)",
            "bodies": [100412, 100413, 100414],
        },
        {
            "id": 1,
            "start_utc": "2026-11-22T13:02:40",
            "end_utc": "2026-11-22T13:31:02",
            "size_mm": 0.148,
            "text": "several groups moved, 14 measurements: waiting for the full recalibration",
        },
    ],
    "events": [
        {
            "utc": "2026-11-23T09:29:51",
            "kind": "window",
            "detail": '{"window": 412, "slots": [7], "measured": 1, "rejected": 0,'
            ' "withdrawn": "", "overrun": false, "note": ""}',
        },
        {
            "utc": "2026-11-23T09:20:00",
            "kind": "calibration",
            "detail": '{"id": 4, "status": "pending", "rms_mm": 0.0398, "holdout_rms_mm": 0.0441,'
            ' "current_holdout_rms_mm": 0.0502, "failures": []}',
        },
        {
            "utc": "2026-11-23T09:12:40",
            "kind": "alarm",
            "detail": '{"id": 7, "code": "drift", "priority": "medium", "message": "drift of P2'
            ' (cusum 0.203 > 0.187 mm): recalibration brought forward"}',
        },
    ],
}


PLC_UNREACHABLE = (
    "plc (plc+modbus://10.0.0.5:502) unreachable: DeviceConnectionError: 10.0.0.5:502: cannot"
    " connect; the service tries again after 1, 2, 5, 10 s, then every 30 s, and leaves FAULT"
    " by itself once every device answers"
)
UNREACHABLE_ALARM: dict[str, Any] = {
    "id": 8,
    "code": "device_unreachable",
    "priority": "urgent",
    "state": "raised",
    "message": PLC_UNREACHABLE,
    "text": PLC_UNREACHABLE,
    "raised_utc": "2026-11-23T09:29:10+00:00",
}
FAULT_STATUS: dict[str, Any] = {
    **STATUS,
    "state": "fault",
    "step": "waiting for plc (unreachable): next try 2026-11-23T09:30:10+00:00",
    "plc": None,  # never read since the start
    "window": {
        "open": False,
        "remaining_s": None,
        "line_running": False,
        "heartbeat_alive": False,
        "plc_answered": False,
    },
    "devices": {
        **STATUS["devices"],
        "plc": {
            "url": "plc+modbus://10.0.0.5:502",
            "state": "unreachable",
            "last_error": "DeviceConnectionError: 10.0.0.5:502: cannot connect",
            "last_error_utc": "2026-11-23T09:29:40+00:00",
        },
    },
    "device_retry": {"attempts": 3, "next_utc": "2026-11-23T09:30:10+00:00", "wait_s": 10.0},
    "alarms": [UNREACHABLE_ALARM, *STATUS["alarms"]],
}
FAULT_HISTORY: dict[str, list[dict[str, Any]]] = {
    **HISTORY,
    "alarms": [
        {**UNREACHABLE_ALARM, "t_acked": None, "acked_uid": None, "shelved_until_utc": ""},
        *HISTORY["alarms"],
    ],
}


class FrozenTui(RvisTui):
    """The terminal showing STATUS and HISTORY (or others) at NOW, attached to nothing."""

    def __init__(
        self,
        status: dict[str, Any] = STATUS,
        history: dict[str, list[dict[str, Any]]] = HISTORY,
    ) -> None:
        super().__init__(Path("/nonexistent/rvis-frozen"))
        self.now = lambda: NOW
        self.status = status
        self.frozen_history = history
        self.connection = (True, "connected")

    def attach(self) -> None:
        self.refresh_all()  # attached to nothing: the frozen data instead

    def _read_history(
        self, wanted: Sequence[str], sphere: str | None, text: str
    ) -> dict[str, list[dict[str, Any]]]:
        return {key: self.frozen_history[key] for key in wanted}

    async def _refresh_once(self) -> None:
        hist = self._read_history(PANE_HISTORY[self.pane], None, "")
        self._show_status()
        self._show_history(hist)
