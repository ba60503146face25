"""The RMI peer answers as the manual says (codes, forms, the packets clients use), and the driver
maps every reply form the manual defines to a typed error at once."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers import DeviceConnectionError, DeviceFault, FaultLatched
from drivers import rmi_errors as rmi
from drivers.rmi import RmiRobot
from fakes.rmi_controller import ERR_RMI_MOVE_SELECTED, RmiController
from fakes.world import StaticWorld

A = np.array([20.0, 5.0, -5.0, 10.0, -80.0, 30.0])
MOTION: dict[str, Any] = {"SpeedType": "Percent", "Speed": 100, "TermType": "FINE", "TermValue": 0}


def toy_pose(q_deg: np.ndarray) -> dict[str, float]:
    """A stand-in forward kinematics: the fake only reports what it is handed."""
    values = [1000.0 + float(q_deg[0]), 0.0, 500.0, 180.0, 0.0, 0.0]
    return dict(zip(("X", "Y", "Z", "W", "P", "R"), values, strict=True))


class RawClient:
    """A plain socket speaking the manual's framing (JSON + CRLF): no driver code involved."""

    def __init__(self, port: int) -> None:
        hello = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        hello.sendall(b'{"Communication": "FRC_Connect"}\r\n')
        session = json.loads(hello.makefile("rb").readline())["PortNumber"]
        hello.close()
        self.sock = socket.create_connection(("127.0.0.1", session), timeout=2.0)
        self.file = self.sock.makefile("rb")

    def send_raw(self, data: bytes) -> dict[str, Any]:
        self.sock.sendall(data + b"\r\n")
        reply: dict[str, Any] = json.loads(self.file.readline())
        return reply

    def ask(self, **packet: Any) -> dict[str, Any]:
        return self.send_raw(json.dumps(packet).encode())

    def close(self) -> None:
        self.file.close()
        self.sock.close()


@pytest.fixture
def ctrl(world: StaticWorld) -> Iterator[RmiController]:
    with RmiController(world, time_scale=0.002, pose_of=toy_pose) as c:
        yield c


@pytest.fixture
def client(ctrl: RmiController) -> Iterator[RawClient]:
    c = RawClient(ctrl.port)
    yield c
    c.close()


@pytest.fixture
def robot(ctrl: RmiController) -> Iterator[RmiRobot]:
    with RmiRobot("127.0.0.1", ctrl.port, timeout_s=2.0, motion_timeout_s=2.0) as r:
        yield r


# -- the driver ------------------------------------------------------------------------------
def test_unknown_packet_reply_is_a_typed_fault_at_once(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    ctrl.fail_next("FRC_GetStatus", "unknown")
    t0 = time.monotonic()
    with pytest.raises(DeviceFault, match="did not understand FRC_GetStatus") as info:
        robot.status()
    assert time.monotonic() - t0 < 1.0  # half the 2 s timeout: not waited for, no reconnect
    assert info.value.code == rmi.INVALID_COMMAND
    assert "RMIT-013 Invalid RMI Command" in str(info.value)
    assert [m for m in ctrl.received if m.get("Communication") == "FRC_Connect"] == [
        {"Communication": "FRC_Connect"}
    ]


def test_unknown_reply_to_a_motion_is_a_latched_fault(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", "unknown")
    t0 = time.monotonic()
    with pytest.raises(DeviceFault) as info:
        robot.move_joints(A, speed_pct=100)
    assert time.monotonic() - t0 < 1.0  # half the 2 s motion timeout
    assert info.value.code == rmi.INVALID_INSTRUCTION
    with pytest.raises(FaultLatched):
        robot.move_joints(A, speed_pct=100)
    robot.reset()
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-3)


def test_system_fault_carries_the_controllers_alarm(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", "system_fault")
    with pytest.raises(DeviceFault, match="SRVO-050"):
        robot.move_joints(A, speed_pct=100)
    assert isinstance(robot.fault, DeviceFault)


def test_initialize_twice_is_handled_by_aborting_first(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    robot.move_joints(A, speed_pct=100)
    robot._initialized = False  # as after a restart of the app: RMI_MOVE still runs
    robot.move_joints(np.array([0.0, 0, 0, 0, -90, 0]), speed_pct=100)
    names = [m.get("Command") for m in ctrl.received if "Command" in m]
    i = names.index("FRC_Initialize", names.index("FRC_Initialize") + 1)
    assert names[i - 1] == "FRC_Abort"  # the driver aborted RMI_MOVE before initialising again


def test_abort_without_rmi_running_sends_no_abort(ctrl: RmiController, robot: RmiRobot) -> None:
    robot.abort()
    assert not [m for m in ctrl.received if m.get("Command") == "FRC_Abort"]


# -- the peer --------------------------------------------------------------------------------
def test_bad_json_and_unknown_packets_get_the_manuals_unknown_form(client: RawClient) -> None:
    unknown = {"Command": "Unknown", "ErrorID": rmi.INVALID_COMMAND}
    assert client.send_raw(b"{not json") == unknown
    assert client.ask(Command="FRC_Bogus") == unknown
    assert client.ask(Foo="bar") == unknown
    assert client.ask(Instruction="FRC_Bogus", SequenceID=1) == {
        "Command": "Unknown",
        "ErrorID": rmi.INVALID_INSTRUCTION,
        "SequenceID": 1,
    }


def test_peer_error_codes_follow_the_manual(client: RawClient) -> None:
    move = {
        "Instruction": "FRC_JointMotionJRep",
        "JointAngle": dict(J1=10, J2=0, J3=0, J4=0, J5=-90, J6=0),
    }
    assert client.ask(Command="FRC_Abort")["ErrorID"] == rmi.COMMAND_FAIL  # RMI not running
    assert client.ask(**move, SequenceID=1, **MOTION)["ErrorID"] == rmi.NOT_RUNNING
    assert client.ask(Command="FRC_Initialize", GroupMask=1)["ErrorID"] == 0
    assert client.ask(Command="FRC_Initialize")["ErrorID"] == ERR_RMI_MOVE_SELECTED
    assert client.ask(**move, SequenceID=2, **MOTION)["ErrorID"] == rmi.INVALID_SEQUENCE
    assert (
        client.ask(**move, SequenceID=1, **MOTION | {"SpeedType": "mmSec"})["ErrorID"]
        == rmi.INVALID_SPEED_TYPE
    )
    assert client.ask(**move, SequenceID=1, **MOTION | {"Speed": 0})["ErrorID"] == rmi.INVALID_SPEED
    assert (
        client.ask(**move, SequenceID=1, **MOTION | {"TermType": "X"})["ErrorID"]
        == rmi.INVALID_TERM_TYPE
    )
    far = move | {"JointAngle": dict(J1=0, J2=140, J3=0, J4=0, J5=0, J6=0)}
    assert client.ask(**far, SequenceID=1, **MOTION)["ErrorID"] == rmi.INVALID_DESTINATION
    assert client.ask(Command="FRC_SetOverRide", Value=0)["ErrorID"] == rmi.INVALID_OVERRIDE
    assert (
        client.ask(Command="FRC_SetUFrameUTool", UFrameNumber=10, UToolNumber=1)["ErrorID"]
        == rmi.INVALID_UFRAME
    )
    assert client.ask(Command="FRC_ReadJointAngles", Group=2)["ErrorID"] == rmi.INVALID_GROUP
    reply = client.ask(**move, SequenceID=1, **MOTION)
    assert reply == {"Instruction": "FRC_JointMotionJRep", "ErrorID": 0, "SequenceID": 1}


def test_read_error_answers_as_the_controller(ctrl: RmiController, client: RawClient) -> None:
    """FRC_ReadError (B-84184EN 2.3.5, FANUC fanuc_driver packets.hpp): Count 1..5 of the
    controller's errors, newest first, in ErrorData, ErrorData2, ...; "No Error" where there is
    none. The peer answered Count 1 whatever was asked, and an empty ErrorData."""
    quiet = client.ask(Command="FRC_ReadError")
    assert quiet == {"Command": "FRC_ReadError", "ErrorID": 0, "Count": 1, "ErrorData": "No Error"}
    ctrl.raise_system_fault()
    assert client.file.readline().startswith(b'{"Communication": "FRC_SystemFault"')
    three = client.ask(Command="FRC_ReadError", Count=3)
    assert three["Count"] == 3 and three["ErrorData"].startswith("SRVO-050 ")
    assert (three["ErrorData2"], three["ErrorData3"]) == ("No Error", "No Error")
    assert "ErrorData4" not in three
    five = client.ask(Command="FRC_ReadError", Count=5)
    assert [k for k in five if k.startswith("ErrorData")] == ["ErrorData"] + [
        f"ErrorData{k}" for k in range(2, 6)
    ]
    for bad in (0, 6, "2", 1.5, True):
        assert client.ask(Command="FRC_ReadError", Count=bad)["ErrorID"] == rmi.INVALID_VALUE
    assert client.ask(Command="FRC_Reset")["ErrorID"] == 0
    assert client.ask(Command="FRC_ReadError")["ErrorData"] == "No Error"


def test_peer_packets_clients_use(
    ctrl: RmiController, client: RawClient, world: StaticWorld
) -> None:
    assert client.ask(Command="FRC_Initialize")["ErrorID"] == 0
    assert client.ask(Command="FRC_SetUFrameUTool", UFrameNumber=3, UToolNumber=2)["ErrorID"] == 0
    got = client.ask(Command="FRC_GetUFrameUTool")
    assert (got["UFrameNumber"], got["UToolNumber"]) == (3, 2)
    rel = {"J1": 5.0, "J2": 0.0, "J3": 0.0, "J4": 0.0, "J5": 0.0, "J6": 0.0}
    before = world.joints_deg()
    reply = client.ask(Instruction="FRC_JointRelativeJRep", SequenceID=1, JointAngle=rel, **MOTION)
    assert reply["ErrorID"] == 0
    np.testing.assert_allclose(
        world.joints_deg(), before + np.array([5.0, 0, 0, 0, 0, 0]), atol=1e-9
    )
    assert client.ask(Instruction="FRC_WaitTime", SequenceID=2, Time=0.5)["ErrorID"] == 0
    assert client.ask(Instruction="FRC_SetUTool", SequenceID=3, ToolNumber=4)["ErrorID"] == 0
    cart = client.ask(Command="FRC_ReadCartesianPosition")
    assert cart["Position"]["X"] == pytest.approx(1000.0 + before[0] + 5.0)
    assert cart["Configuration"]["UToolNumber"] == 4
    assert cart["Configuration"]["UFrameNumber"] == 3
    ctrl.raise_system_fault()
    assert client.file.readline().startswith(b'{"Communication": "FRC_SystemFault"')
    assert "SRVO-050" in client.ask(Command="FRC_ReadError")["ErrorData"]
    assert client.ask(Command="FRC_Initialize")["ErrorID"] == rmi.SERVO_OFF
    assert client.ask(Command="FRC_Reset")["ErrorID"] == 0
    assert client.ask(Command="FRC_Initialize")["ErrorID"] == 0


def test_cartesian_position_needs_the_kinematics(world: StaticWorld) -> None:
    with RmiController(world) as bare:
        c = RawClient(bare.port)
        try:
            assert c.ask(Command="FRC_ReadCartesianPosition")["ErrorID"] == rmi.INTERNAL_ERROR
        finally:
            c.close()


class _MovingWorld(StaticWorld):
    def __init__(self) -> None:
        super().__init__()
        self.moved = threading.Event()

    def set_joints_deg(self, q_deg: Any) -> None:
        super().set_joints_deg(q_deg)
        self.moved.set()


def test_terminate_during_a_motion_is_a_connection_error_at_once() -> None:
    world = _MovingWorld()
    with (
        RmiController(world, time_scale=1.0) as slow,  # the move takes seconds
        RmiRobot("127.0.0.1", slow.port, timeout_s=5.0, motion_timeout_s=10.0) as robot,
    ):
        failure: list[BaseException] = []
        moving = threading.Thread(target=lambda: _move_catching(robot, A, failure))
        moving.start()
        assert world.moved.wait(2.0), "the motion never started"
        t0 = time.monotonic()
        slow.terminate_sessions()
        moving.join(5.0)
        assert time.monotonic() - t0 < 2.5  # half the 5 s timeout: at once
        assert len(failure) == 1 and isinstance(failure[0], DeviceConnectionError)
        assert isinstance(robot.fault, DeviceConnectionError)  # the robot's state is unknown


def test_unsolicited_system_fault_while_idle_is_reported_by_the_next_request(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    robot.joints_deg()
    ctrl.raise_system_fault()
    with pytest.raises(DeviceFault, match=r"system fault.*SRVO-050"):
        robot.joints_deg()
    assert isinstance(robot.fault, DeviceFault)


def _move_catching(robot: RmiRobot, q: np.ndarray, out: list[BaseException]) -> None:
    try:
        robot.move_joints(q, speed_pct=10)
    except BaseException as exc:
        out.append(exc)
