"""Sensor device faults through the service on the RENDERED simulated line: the service measures
through the real drivers over loopback (Aravis GigE fake camera streaming rendered frames, SCPI
DAC on a pty, RMI controller, Modbus PLC) and a peer plays the fault during a clamp window
(`SimLine.schedule`). Checked against what the peers really saw, as the geometric fault tests
(tests/sim/test_line_service_faults.py) check the motion faults: the service's state, the urgent
alarm naming the driver's typed error, the fault bit the PLC peer received, the robot's true
joints not moving until a reset, and every measurement the service announced stored. A frame
lost once is re-triggered by the camera driver and is not a fault.

The line is shortened for speed (8-frame sweeps, an 8 s clamp period, the fault in the first
window); it runs in virtual time, as fast as the renderer. The galvo error and the camera
timeout (the same path, two grab timeouts longer) and the camera switched off and on (opened
again by the operator's reset) are marked slow: `-m "not slow"` leaves them
out of a quick run; the test command runs them."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.config import CellConfig
from app.line.states import State
from app.sim.line_run import SimulatedLineRun
from fakes.line_faults import Fault
from tests.groups import GIGE_CAMERA
from tests.sim.fault_checks import all_announced_stored, faulted

pytestmark = GIGE_CAMERA

WAIT_S = 20.0


def _short_line(cfg: CellConfig) -> CellConfig:
    """The rendered line with short sweeps and short clamp cycles (sim seconds)."""
    simline = dataclasses.replace(
        cfg.simline, period_s=8.0, window_s=7.0, warmup_k=0.0, n_validation=4
    )
    sweep = dataclasses.replace(cfg.sweep, n_frames=8, grab_timeout_s=0.5)
    return dataclasses.replace(cfg, simline=simline, sweep=sweep)


@pytest.fixture()
def run(cfg: CellConfig, tmp_path: Path) -> Iterator[SimulatedLineRun]:
    with SimulatedLineRun(_short_line(cfg), tmp_path / "state", seed=5, geometric=False) as sim:
        sim.start_service()
        yield sim


def _until(run: SimulatedLineRun, pred: Any) -> list[dict[str, Any]]:
    """The service's events up to the first one `pred` accepts, within WAIT_S (the events of
    passing windows never keep a failing wait alive)."""
    seen, deadline = [], time.monotonic() + WAIT_S
    for event in run.events_until(lambda e: pred(e) or time.monotonic() > deadline, WAIT_S):
        seen.append(event)
    assert pred(seen[-1]), f"not within {WAIT_S:g} s; last events: {seen[-5:]}"
    return seen


def _sensor_fault(run: SimulatedLineRun, fault: Fault, cause: str) -> None:
    """`fault` played as window 0 opens (it hits the sweep, the robot out): FAULT, alarm, PLC
    fault bit, no motion over the next window, back to measuring after the operator's reset."""
    played = run.line.schedule(fault, window=0, after_s=0.0)
    events = _until(run, lambda e: e["event"] == "alarm" and e["code"] == "device_fault")
    assert played.is_set()
    faulted(run, events, cause)
    q_stopped = run.cell.joints_deg().copy()
    home = np.array(run.service.settings.line.home_deg)
    assert np.abs(q_stopped - home).max() > 1.0  # stopped out, where the sweep failed
    later = run.line.schedule(Fault.WINDOW_WITHDRAWN, window=1, after_s=0.0)
    assert later.wait(WAIT_S)  # window 1 opened (and was withdrawn): no motion, still FAULT
    assert run.service.state == State.FAULT
    np.testing.assert_allclose(run.cell.joints_deg(), q_stopped, atol=1e-9)
    assert not [e for e in events if e["event"] == "measurement"]  # nothing half-measured
    run.line.clear(fault)
    reply = run.service.request("reset").result(timeout=WAIT_S)
    assert reply["ok"], reply
    more = _until(run, lambda e: e["event"] == "measurement" and e["status"] == "ok")
    assert not run.line.plc.received.fault and run.service.state != State.FAULT
    assert not run.service.store.active_alarms(code="device_fault")
    all_announced_stored(run, events + more)


@pytest.mark.slow  # about 14 s (three clamp periods at time x2): the suite's representative
def test_galvo_scpi_error_faults_the_rendered_service(run: SimulatedLineRun) -> None:
    _sensor_fault(run, Fault.GALVO_ERROR, "DeviceFault")


@pytest.mark.slow
def test_camera_timeout_faults_the_rendered_service(run: SimulatedLineRun) -> None:
    _sensor_fault(run, Fault.CAMERA_TIMEOUT, "DeviceTimeout")


def test_a_frame_lost_once_is_retriggered_and_is_not_a_fault(run: SimulatedLineRun) -> None:
    camera = run.line.camera
    assert camera is not None
    camera.lose_next_frame()  # the first frame of window 0's sweep never arrives
    events = _until(run, lambda e: e["event"] == "window")
    assert camera.frames_lost == 1
    (measured,) = [e for e in events if e["event"] == "measurement"]
    assert measured["status"] == "ok"
    assert run.service.state != State.FAULT and not run.line.plc.received.fault
    assert not [e for e in events if e["event"] == "alarm"]
    assert (
        run.service.decision.counters["overruns"] == 0
    )  # this window had room for the extra timeout
    all_announced_stored(run, events)


@pytest.mark.slow  # about 12 s
def test_a_camera_switched_off_and_on_is_opened_again_by_the_reset(run: SimulatedLineRun) -> None:
    """`devices ctl stop camera` / `start camera` (issue 51): the Aravis driver marks the
    camera that went away lost; the operator's reset opens it again (refused while it does not
    answer), and the robot goes out and measures instead of faulting again."""
    _until(run, lambda e: e["event"] == "measurement" and e["status"] == "ok")
    run.line.stop_device("camera")
    events = _until(run, lambda e: e["event"] == "alarm" and e["code"] == "device_fault")
    assert events[-1]["message"].startswith("camera (aravis://")
    refused = run.service.request("reset").result(timeout=WAIT_S)
    assert not refused["ok"] and refused["error"].startswith("camera (aravis://"), refused
    assert "a restart is needed" in refused["error"]
    assert run.service.state == State.FAULT
    run.line.start_device("camera")
    reply = run.service.request("reset").result(timeout=WAIT_S)
    assert reply["ok"], reply
    # (the robot, stopped out, comes home in the first window)
    more = _until(run, lambda e: e["event"] == "alarm" or e.get("status") == "ok")
    assert more[-1]["event"] == "measurement", more[-1]  # not faulted again
    assert run.service.status()["devices"]["camera"]["state"] == "ok"
    all_announced_stored(run, events + more)
