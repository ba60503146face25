"""Modbus mailbox robot against the pymodbus server emulating the TP program: faults."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers import (
    CommunicationError,
    DeviceConnectionError,
    DeviceFault,
    DeviceTimeout,
    FaultLatched,
)
from drivers._modbus import floats_to_words, words_to_floats
from drivers.modbus_robot import MAILBOX, ModbusRobot
from fakes.modbus_robot import ERR_LIMIT, ModbusRobotServer
from fakes.world import StaticWorld

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
A = np.array([20.0, 5.0, -5.0, 10.0, -80.0, 30.0])


@pytest.fixture
def server(world: StaticWorld) -> Iterator[ModbusRobotServer]:
    with ModbusRobotServer(world, time_scale=0.002) as s:
        yield s


@pytest.fixture
def robot(server: ModbusRobotServer) -> Iterator[ModbusRobot]:
    with ModbusRobot("127.0.0.1", server.port, timeout_s=0.5, poll_s=0.002) as r:
        yield r


@pytest.mark.parametrize("order", ["little", "big"])
def test_float_words_round_trip(order: str) -> None:
    values = [0.0, -90.0, 123.456, 1e-3, 9999.0]
    back = words_to_floats(floats_to_words(values, order), order)  # type: ignore[arg-type]
    np.testing.assert_allclose(back, values, rtol=1e-7)
    assert floats_to_words([1.0], "little") == [0x0000, 0x3F80]


def test_tp_fault_mid_motion_latches_until_reset(
    server: ModbusRobotServer, robot: ModbusRobot, world: StaticWorld
) -> None:
    server.fault_next_motion(4242)
    with pytest.raises(DeviceFault, match="4242") as info:
        robot.move_joints(A, speed_pct=100)
    assert info.value.code == 4242
    assert robot.status().fault
    with pytest.raises(FaultLatched):
        robot.move_joints(HOME, speed_pct=100)
    robot.reset()
    assert not robot.status().fault
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-4)


def test_the_tp_program_refuses_what_the_guard_would_too(
    server: ModbusRobotServer, robot: ModbusRobot
) -> None:
    # bypass the guard on purpose: the peer must refuse on its own
    with pytest.raises(DeviceFault) as info:
        robot._move(np.array([0.0, 150.0, 0, 0, 0, 0]), 50.0, 1.0)
    assert info.value.code == ERR_LIMIT


def test_modbus_exception_is_a_device_fault(server: ModbusRobotServer, robot: ModbusRobot) -> None:
    server.fail_next("exception")
    with pytest.raises(DeviceFault):
        robot._read_joints()
    np.testing.assert_allclose(robot.joints_deg(), HOME, atol=1e-4)


def test_no_reply_is_a_timeout_and_a_read_retries(
    server: ModbusRobotServer, robot: ModbusRobot
) -> None:
    server.fail_next("mute")
    with pytest.raises(DeviceTimeout):
        robot._read_joints()
    server.fail_next("mute")
    np.testing.assert_allclose(robot.joints_deg(), HOME, atol=1e-4)  # reconnect + retry


def test_peer_disconnect_mid_motion_latches(server: ModbusRobotServer, robot: ModbusRobot) -> None:
    server.fail_next("drop", function_code=16)  # the speed/target write of the next move
    with pytest.raises((DeviceConnectionError, DeviceTimeout)):
        robot.move_joints(A, speed_pct=100)
    assert robot.fault is not None
    robot.reset()
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-4)


def test_cannot_connect() -> None:
    with pytest.raises(DeviceConnectionError):
        ModbusRobot("127.0.0.1", 1, timeout_s=0.3).open()


def test_garbled_reply_is_a_communication_error_and_a_read_retries(
    server: ModbusRobotServer, robot: ModbusRobot
) -> None:
    server.fail_next("garble")
    with pytest.raises(CommunicationError):  # pymodbus drops the bad frame, then times out
        robot._read_joints()
    server.fail_next("garble")
    np.testing.assert_allclose(robot.joints_deg(), HOME, atol=1e-4)  # reconnect + retry


def test_garbled_reply_mid_motion_latches_until_reset(
    server: ModbusRobotServer, robot: ModbusRobot, world: StaticWorld
) -> None:
    server.fail_next("garble", function_code=16)
    with pytest.raises(CommunicationError):
        robot.move_joints(A, speed_pct=100)
    moves = world.moves
    with pytest.raises(FaultLatched):
        robot.move_joints(A, speed_pct=100)
    assert world.moves == moves  # nothing sent after the fault
    robot.reset()
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-4)


def test_controller_gone_and_back(world: StaticWorld) -> None:
    server = ModbusRobotServer(world, time_scale=0.002).start()
    try:
        with ModbusRobot("127.0.0.1", server.port, timeout_s=0.5, poll_s=0.002) as robot:
            port = server.port
            server.close()
            with pytest.raises(DeviceConnectionError):
                robot.joints_deg()  # the retry's reconnect is refused too
            with pytest.raises(DeviceConnectionError):
                robot.move_joints(A, speed_pct=100)  # the guard cannot read where it is
            assert robot.fault is None  # nothing was sent: no latch
            server = ModbusRobotServer(world, time_scale=0.002, port=port).start()
            np.testing.assert_allclose(robot.joints_deg(), HOME, atol=1e-4)
            np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-4)
    finally:
        server.close()


def test_the_tp_listing_serves_the_drivers_mailbox_over_modbus_tcp() -> None:
    """docs/RVIS_MBX.ls: its first line names the protocol it serves (Modbus TCP; it said "R553
    SNPX", HMI Device, a different protocol), and every R[] it uses sits at the word offset
    the driver reads or writes (R[n] at words 2 (n - 1), a REAL in two words)."""
    text = (Path(__file__).resolve().parents[2] / "docs" / "RVIS_MBX.ls").read_text()
    first = re.search(r"^\s+1:\s+!(.*);$", text, re.M)
    assert first is not None and "Modbus TCP" in first.group(1)
    assert "SNPX" not in text and "R553" not in text
    offsets = {
        "CMD": MAILBOX.CMD,
        "SPEED": MAILBOX.SPEED,
        **{f"J{i + 1}": MAILBOX.TARGET + 2 * i for i in range(6)},
        "ACK": MAILBOX.ACK,
        "DONE": MAILBOX.DONE,
        "STATUS": MAILBOX.STATUS,
        "ERROR": MAILBOX.ERROR,
    }
    used = set(re.findall(r"(?<![A-Z])R\[(\d+):([A-Z0-9]+)\]", text))
    assert {name for _, name in used} == set(offsets)
    for number, name in used:
        assert 2 * (int(number) - 1) == offsets[name], name
