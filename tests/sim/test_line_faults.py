"""Fault injection on the simulated line: each fault, played by the peer the real driver talks
to, gives the typed driver error (or, for a withdrawn window, the PLC signal), and the device
works again once the fault is cleared or reset. In virtual time (the test makes it pass where
nothing else does), except the PLC heartbeat, whose loss the driver judges on the wall clock:
that test runs the line on a scaled clock."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers import registry
from drivers.errors import DeviceConnectionError, DeviceFault, DeviceTimeout, FaultLatched
from fakes.cell import SimulatedCell
from fakes.line import SimLine, SimLineSetup
from fakes.line_faults import GALVO_ERROR_CODE, Fault
from tests.groups import GIGE_CAMERA

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
AWAY = HOME + np.array([60.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 3.43 sim s at 10 %


@pytest.fixture()
def line(line_cell: SimulatedCell) -> Iterator[SimLine]:
    with SimLine(line_cell, SimLineSetup(camera=False)) as sim:
        yield sim


def test_plc_heartbeat_loss_is_a_timeout_waiting_for_the_window(line_cell: SimulatedCell) -> None:
    with (
        SimLine(line_cell, SimLineSetup(scale=120.0, clock="scaled", camera=False)) as line,
        registry.open_plc(line.urls["plc"], poll_s=0.005, heartbeat_timeout_s=0.1) as plc,
    ):
        line.inject(Fault.PLC_HEARTBEAT_LOSS)
        with pytest.raises(DeviceTimeout, match="heartbeat lost"):
            plc.wait_window(timeout_s=0.8)  # > one clamp period (0.5 s real)
        assert not plc.heartbeat_alive()
        line.clear(Fault.PLC_HEARTBEAT_LOSS)
        assert plc.wait_window(timeout_s=1.0).window_open and plc.heartbeat_alive()


def test_a_withdrawn_window_closes_early_and_the_next_one_opens(line: SimLine) -> None:
    opens, closes = line.window_bounds_s(0)
    with registry.open_plc(line.urls["plc"], poll_s=0.002) as plc:
        line.clock.advance(opens + 2.0)
        assert plc.poll().window_open
        line.inject(Fault.WINDOW_WITHDRAWN)
        inputs = plc.poll()
        assert not inputs.window_open and inputs.line_running
        line.clock.advance(closes - opens - 4.0)  # the PLC's cycle would still have it open
        assert not plc.poll().window_open
        next_opens, _ = line.window_bounds_s(1)
        line.clock.advance(next_opens + 1.0 - line.clock.monotonic())
        assert plc.poll().window_open


def test_robot_disconnect_mid_move_is_a_connection_error_and_latches(
    line: SimLine, line_cell: SimulatedCell
) -> None:
    with registry.open_robot(line.urls["robot"]) as robot:
        line.inject(Fault.ROBOT_DISCONNECT)
        with pytest.raises(DeviceConnectionError):
            robot.move_joints(AWAY, speed_pct=10)
        j1 = line_cell.joints_deg()[0]
        assert j1 == pytest.approx(30.0)  # stopped half-way, not at 60
        with pytest.raises(FaultLatched):
            robot.move_joints(HOME, speed_pct=10)
        robot.reset()  # reconnects: the sessions are gone
        np.testing.assert_allclose(robot.move_joints(AWAY, speed_pct=100), AWAY, atol=1e-4)


def test_controller_alarm_mid_move_is_a_device_fault_until_reset(
    line: SimLine, line_cell: SimulatedCell
) -> None:
    with registry.open_robot(line.urls["robot"]) as robot:
        line.inject(Fault.CONTROLLER_ALARM)
        with pytest.raises(DeviceFault, match="system fault"):
            robot.move_joints(AWAY, speed_pct=10)
        assert line.controller.alarm and robot.status().fault
        assert line_cell.joints_deg()[0] == pytest.approx(30.0)
        robot.reset()
        assert not line.controller.alarm
        np.testing.assert_allclose(robot.move_joints(AWAY, speed_pct=100), AWAY, atol=1e-4)


def test_galvo_scpi_error_is_a_device_fault_with_the_dac_code(line: SimLine) -> None:
    with registry.open_galvo(line.urls["galvo"]) as galvo:
        line.inject(Fault.GALVO_ERROR)
        with pytest.raises(DeviceFault) as err:
            galvo.set_volts(0.5)
        assert err.value.code == GALVO_ERROR_CODE and line.dac.volts == 0.0  # not executed
        galvo.set_volts(0.5)
        assert line.dac.volts == pytest.approx(0.5)


@GIGE_CAMERA
def test_camera_timeout_until_cleared(line_cell: SimulatedCell) -> None:
    with (
        SimLine(line_cell, SimLineSetup()) as sim,
        registry.open_camera(sim.urls["camera"], timeout_s=0.3) as camera,
    ):
        first = camera.grab()
        sim.inject(Fault.CAMERA_TIMEOUT)
        with pytest.raises(DeviceTimeout):
            camera.grab()  # the driver re-triggers once, then gives up
        sim.clear(Fault.CAMERA_TIMEOUT)
        again = camera.grab(timeout_s=2.0)
        assert again.frame_id > first.frame_id
        with pytest.raises(DeviceTimeout):  # no stale frame left over for the lost triggers
            camera._grab(0.3)


def test_a_fault_scheduled_in_a_window_is_played_when_that_window_opens(line: SimLine) -> None:
    played = line.schedule(Fault.CONTROLLER_ALARM, window=1, after_s=2.0)
    opens, _ = line.window_bounds_s(1)
    with registry.open_robot(line.urls["robot"]) as robot:
        robot.move_joints(AWAY, speed_pct=100)  # nothing armed yet
        line.clock.advance(opens + 1.5 - line.clock.monotonic())
        assert not played.is_set()
        line.clock.advance(1.0)
        assert played.is_set()  # at its sim time, in the thread that made time pass
        ((fault, at_s),) = line.faults.played
        assert fault is Fault.CONTROLLER_ALARM and at_s == opens + 2.0
        with pytest.raises(DeviceFault, match="system fault"):
            robot.move_joints(HOME, speed_pct=10)
