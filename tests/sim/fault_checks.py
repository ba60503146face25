"""What every device-fault test of the simulated line checks, on the peers' side and the
service's: the urgent alarm with its cause, FAULT, the PLC fault bit, nothing announced lost."""

from __future__ import annotations

from typing import Any

from app.line.states import State
from app.sim.line_run import SimulatedLineRun


def all_announced_stored(run: SimulatedLineRun, events: list[dict[str, Any]]) -> None:
    """Every measurement the service announced is a row in the database (good or rejected)."""
    announced = {e["id"] for e in events if e["event"] == "measurement"}
    store = run.service.store
    stored = {r["id"] for s in ("ok", "rejected") for r in store.measurements(status=s)}
    assert announced and announced <= stored


def faulted(run: SimulatedLineRun, events: list[dict[str, Any]], cause: str) -> None:
    """The last event is the urgent device_fault alarm naming `cause`; the service is in FAULT,
    the alarm is in the database, and the PLC peer saw the fault bit and busy dropped."""
    assert run.service.state == State.FAULT
    assert cause in events[-1]["message"] and events[-1]["priority"] == "urgent"
    alarm = run.service.store.active_alarms(code="device_fault")
    assert alarm and cause in alarm[0]["message"]
    assert run.line.plc.received.fault and not run.line.plc.received.busy
