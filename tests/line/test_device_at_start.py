"""A device unreachable at start (issue 30, item 4), in process on the service's virtual clock:
FAULT with a `device_unreachable` alarm naming it, the operator's commands answered (a reset
refused with the reason), retries after 1, 2, 5, 10, then every 30 s of the service's clock;
once the device answers the alarm clears by itself and the next window is measured. A stop
during the retries ends run() at once. The real process: tests/ops/test_device_at_start.py."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from app.line.startup import DEVICE_RETRY_S
from app.line.states import ALARM_CODES, FAULT_CODES
from drivers.errors import DeviceConnectionError
from tests.line.helpers import Line, make_line


def _plc_unreachable(ln: Line, monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """The line's PLC closed and refusing to open until `gate[0]` is True; the station built
    as Station.open(defer_unreachable=True) leaves it."""
    gate = [False]
    connect = ln.plc._connect

    def refuse() -> None:
        if not gate[0]:
            raise DeviceConnectionError("127.0.0.1:502: cannot connect")
        connect()

    ln.plc.close()
    monkeypatch.setattr(ln.plc, "_connect", refuse)
    try:
        ln.plc.open()
    except DeviceConnectionError as exc:
        exc.family = "plc"
        ln.service.station.unreachable = {"plc": exc}
    return gate


def test_the_service_waits_in_fault_retrying_with_back_off_then_measures(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert "device_unreachable" in ALARM_CODES and "device_unreachable" not in FAULT_CODES
    ln = make_line(tmp_path)
    gate = _plc_unreachable(ln, monkeypatch)
    ln.start()
    try:
        alarm = ln.wait(lambda e: e["event"] == "alarm")
        assert alarm["code"] == "device_unreachable" and alarm["priority"] == "urgent"
        assert alarm["message"].startswith("plc () unreachable: DeviceConnectionError")
        status = ln.service.status()
        assert status["state"] == "fault" and status["devices"]["plc"]["state"] == "unreachable"
        assert status["devices"]["robot"]["state"] == "ok"
        assert status["device_retry"]["attempts"] == 0 and "waiting for plc" in status["step"]
        reply = ln.service.request("reset").result(10)
        assert not reply["ok"] and "no reset needed" in reply["error"]
        retries = [ln.wait(lambda e: e["event"] == "device_retry") for _ in range(6)]
        times = [alarm["t"]] + [r["t"] for r in retries]
        waits = [round(b - a, 1) for a, b in itertools.pairwise(times)]
        assert waits == [*DEVICE_RETRY_S, DEVICE_RETRY_S[-1]] == [1, 2, 5, 10, 30, 30]
        assert ln.service.state.value == "fault"

        gate[0] = True  # the PLC answers now
        opened = ln.wait(lambda e: e["event"] == "devices_opened", 60)
        assert opened["attempts"] == 7
        ln.wait(lambda e: e["event"] == "state" and e["to"] == "idle")
        ln.wait(lambda e: e["event"] == "measurement", 30)
        status = ln.service.status()
        assert not [a for a in status["alarms"] if a["code"] == "device_unreachable"]
        assert status["devices"]["plc"]["state"] == "ok" and status["device_retry"] is None
        assert not ln.plc.received.fault  # the PLC's fault bit taken back
    finally:
        ln.close()


def test_a_stop_during_the_retries_ends_the_service_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ln = make_line(tmp_path)
    _plc_unreachable(ln, monkeypatch)
    ln.start()
    try:
        ln.wait(lambda e: e["event"] == "alarm" and e["code"] == "device_unreachable")
        ln.stop()  # joins the loop within 20 s (asserted), long before the 30 s retries
        assert ln.service.exit_code == 0 and ln.service.state.value == "stopped"
    finally:
        ln.close()
