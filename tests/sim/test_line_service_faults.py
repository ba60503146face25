"""Fault injection through the simulated line: the service talks to the line's peers through the
real drivers over loopback (SimulatedLineRun, geometric) and a fault is played by a peer during a
clamp window (`SimLine.schedule`). Checked against what the peers really saw: the service's
state, the alarm and its cause, the fault bit the PLC peer received, the robot's true joints not
moving until a reset, and every measurement of a window reported done in the database. The line
runs in virtual time, as fast as the CPU: a fault scheduled at a sim time lands at the same point
of the run every time; the test's own actions (inject, reset) come whenever its thread gets to
them, so what follows them is scheduled from the line's clock."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.config import CellConfig
from app.line.states import State
from app.sim.line_records import LineFaulted
from app.sim.line_run import SimulatedLineRun
from fakes.line_faults import Fault
from tests.sim.fault_checks import all_announced_stored, faulted

WAIT_S = 10.0


@pytest.fixture()
def run(cfg: CellConfig, tmp_path: Path) -> Iterator[SimulatedLineRun]:
    with SimulatedLineRun(cfg, tmp_path / "state", seed=5, geometric=True) as sim:
        sim.start_service()
        yield sim


def _until(run: SimulatedLineRun, pred: Any) -> list[dict[str, Any]]:
    seen = []
    for event in run.events_until(pred, WAIT_S):
        seen.append(event)
    return seen


def _windows_done(events: list[dict[str, Any]]) -> int:
    return sum(e["event"] == "window" for e in events)


def _plc_window_from_now(run: SimulatedLineRun, k: int) -> int:
    """The index of the PLC's clamp window k windows after the one of the line's time now."""
    return int(run.clock.monotonic() // run.line.settings.period_s) + k


def _motion_fault(run: SimulatedLineRun, fault: Fault, cause: str) -> None:
    played = run.line.schedule(fault, window=2, after_s=1.0)
    events = _until(run, lambda e: e["event"] == "alarm" and e["code"] == "device_fault")
    assert played.is_set()
    faulted(run, events, cause)
    q_stopped = run.cell.joints_deg().copy()
    # two more windows open and close on the line: no motion, still FAULT
    later = run.line.schedule(Fault.WINDOW_WITHDRAWN, window=_plc_window_from_now(run, 2))
    assert later.wait(WAIT_S)
    assert run.service.state == State.FAULT
    np.testing.assert_allclose(run.cell.joints_deg(), q_stopped, atol=1e-9)
    all_announced_stored(run, events)
    # a reset clears the fault bit; the robot comes home and measures again
    reply = run.service.request("reset").result(timeout=WAIT_S)
    assert reply["ok"], reply
    more = _until(run, lambda e: e["event"] == "measurement" and e["status"] == "ok")
    assert not run.line.plc.received.fault and run.service.state != State.FAULT
    assert not run.service.store.active_alarms(code="device_fault")
    all_announced_stored(run, events + more)


def test_robot_disconnect_mid_move_faults_the_service(run: SimulatedLineRun) -> None:
    _motion_fault(run, Fault.ROBOT_DISCONNECT, "DeviceConnectionError")


def test_controller_alarm_mid_move_faults_the_service(run: SimulatedLineRun) -> None:
    _motion_fault(run, Fault.CONTROLLER_ALARM, "DeviceFault")


def test_plc_heartbeat_loss_raises_the_alarm_and_no_window_is_used(run: SimulatedLineRun) -> None:
    before = _until(run, lambda e: e["event"] == "window")
    run.line.inject(Fault.PLC_HEARTBEAT_LOSS)
    events = _until(run, lambda e: e["event"] == "alarm" and e["code"] == "plc_heartbeat")
    q_lost = run.cell.joints_deg().copy()
    n_windows = run.service.decision.counters["windows"]
    later = run.line.schedule(Fault.WINDOW_WITHDRAWN, window=_plc_window_from_now(run, 3))
    assert later.wait(WAIT_S)
    assert run.service.decision.counters["windows"] <= n_windows + 1  # at most the one in progress
    np.testing.assert_allclose(run.cell.joints_deg(), q_lost, atol=1e-9)
    run.line.clear(Fault.PLC_HEARTBEAT_LOSS)
    after = _until(run, lambda e: e["event"] == "window")
    assert not run.service.store.active_alarms(code="plc_heartbeat")
    all_announced_stored(run, before + events + after)


def test_a_window_withdrawn_early_aborts_and_goes_home(run: SimulatedLineRun) -> None:
    # window 1 is withdrawn 1.5 s after it opens: the service sees it open within a poll
    # ([simline] poll_s, 1 s) and is out measuring then (a sweep alone takes 1.2 s)
    played = run.line.schedule(Fault.WINDOW_WITHDRAWN, window=1, after_s=1.5)
    events = _until(run, lambda e: e["event"] == "window")
    events += _until(run, lambda e: e["event"] == "window")
    assert played.is_set()
    assert run.service.decision.counters["withdrawn"] == 1 and events[-1]["withdrawn"]
    assert run.service.state != State.FAULT and not run.line.plc.received.fault
    home = np.array(run.service.settings.line.home_deg)
    np.testing.assert_allclose(run.cell.joints_deg(), home, atol=0.05)
    assert run.service.decision.counters["overruns"] == 0
    all_announced_stored(run, events)


def test_a_fault_nobody_clears_ends_an_unattended_run(run: SimulatedLineRun) -> None:
    """An experiment's line has no operator to reset a FAULT: the run ends with the device's
    alarm in one line (it waited for ever before), the service stopped."""
    run.line.schedule(Fault.CONTROLLER_ALARM, window=2, after_s=1.0)
    with pytest.raises(LineFaulted, match=r"nobody resets.*DeviceFault") as ended:
        run.run_windows(6)
    assert ended.value.summary.windows < 6
    assert ended.value.summary.fault is not None and "DeviceFault" in ended.value.summary.fault
    assert run.thread is not None
    run.thread.join(WAIT_S)
    assert not run.thread.is_alive()
