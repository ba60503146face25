"""RMI interop:

- fanuc-rmi 0.3.1 (a third-party RMI client) against our RMI controller peer. Its own bugs, worked
  around here: it reads the session port from a ``Port`` field, while the manual's FRC_Connect
  reply names it ``PortNumber`` (so it needs ``main_port=`` set by hand); it sleeps
  ``startup_pause`` after connecting (set to 0); it prints every reply and appends the read
  positions to files (``output_path`` under tmp_path).
- our RMI driver against a small controller written from the manual's packet forms alone (no code
  of our peer): it answers FRC_Initialize, FRC_GetStatus, FRC_ReadJointAngles,
  FRC_JointMotionJRep, FRC_Abort and FRC_Disconnect, and the unknown-packet form to anything else.
"""

from __future__ import annotations

import json
import socketserver
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fanuc_rmi import RobotClient

from drivers import DeviceFault
from drivers.rmi import RmiRobot
from fakes.rmi_controller import RmiController
from fakes.world import StaticWorld


def toy_pose(q_deg: np.ndarray) -> dict[str, float]:
    return {"X": 1500.0 + float(q_deg[0]), "Y": 0.0, "Z": 800.0, "W": 180.0, "P": 0.0, "R": 0.0}


@pytest.fixture
def ctrl(world: StaticWorld) -> Iterator[RmiController]:
    with RmiController(world, time_scale=0.002, pose_of=toy_pose) as c:
        yield c


@pytest.fixture
def fanuc(ctrl: RmiController) -> Iterator[RobotClient]:
    client = RobotClient(
        host="127.0.0.1",
        startup_port=ctrl.port,
        main_port=ctrl.session_port,  # its bug: it looks for "Port", not "PortNumber"
        socket_timeout=2.0,
        reader_timeout=2.0,
        attempts=1,
        startup_pause=0.0,
    )
    client.connect()
    yield client
    client.close()


def test_fanuc_rmi_session_reads_and_frames(
    fanuc: RobotClient, ctrl: RmiController, world: StaticWorld, tmp_path: Path
) -> None:
    fanuc.initialize(uframe=2, utool=3)  # FRC_Reset, FRC_Initialize, FRC_SetUFrameUTool
    assert fanuc.get_uframe_utool() == {"UFrameNumber": 2, "UToolNumber": 3}
    joints = fanuc.read_joint_coordinates(output_path=str(tmp_path / "j.jsonl"))
    assert joints["ErrorID"] == 0
    assert [joints["JointAngle"][f"J{i}"] for i in range(1, 7)] == pytest.approx(
        list(world.joints_deg())
    )
    cart = fanuc.read_cartesian_coordinates(output_path=str(tmp_path / "c.jsonl"))
    assert cart["Position"]["X"] == pytest.approx(1500.0 + world.joints_deg()[0])
    assert cart["Configuration"]["UToolNumber"] == 3
    fanuc.speed_override(50)
    assert ctrl.override_pct == 50


def test_fanuc_rmi_motion_wait_and_abort(
    fanuc: RobotClient, ctrl: RmiController, world: StaticWorld
) -> None:
    fanuc.initialize()
    target = {"J1": 15.0, "J2": 5.0, "J3": -5.0, "J4": 0.0, "J5": -80.0, "J6": 10.0}
    fanuc.joint_absolute(target, speed_percentage=100, sequence_id=1)
    np.testing.assert_allclose(world.joints_deg(), list(target.values()), atol=1e-9)
    delta = {"J1": -5.0, "J2": 0.0, "J3": 0.0, "J4": 0.0, "J5": 0.0, "J6": 0.0}
    fanuc.joint_relative(delta, speed_percentage=100, sequence_id=2)
    assert world.joints_deg()[0] == pytest.approx(10.0)
    fanuc.wait_time(0.5, sequence_id=3)
    replies = [m for m in ctrl.received if m.get("Instruction")]
    assert [m["SequenceID"] for m in replies] == [1, 2, 3]
    assert fanuc.abort() == {"Command": "FRC_Abort", "ErrorID": 0}
    error = fanuc.read_error({"ErrorID": 1})  # it asks FRC_ReadError after any non-zero ErrorID
    assert error["Command"] == "FRC_ReadError" and error["ErrorID"] == 0


class _Port(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, controller: ManualController) -> None:
        super().__init__(("127.0.0.1", 0), _Session)
        self.controller = controller
        threading.Thread(target=self.serve_forever, args=(0.05,), daemon=True).start()


class ManualController:
    """A controller written from the RMI manual's packet forms (connect port + session port)."""

    def __init__(self) -> None:
        self.joints = {f"J{i}": 0.0 for i in range(1, 10)} | {"J5": -90.0}
        self.running = False
        self.next_seq = 1
        self.heard: list[dict[str, Any]] = []
        self.connect, self.session = _Port(self), _Port(self)
        self.port = self.connect.server_address[1]

    def stop(self) -> None:
        for server in (self.connect, self.session):
            server.shutdown()
            server.server_close()

    def answer(self, packet: dict[str, Any]) -> dict[str, Any]:
        self.heard.append(packet)
        name = packet.get("Communication") or packet.get("Command") or packet.get("Instruction")
        if name == "FRC_Connect":
            port = self.session.server_address[1]
            return {"Communication": name, "ErrorID": 0, "PortNumber": port, "MajorVersion": 3,
                    "MinorVersion": 1}  # fmt: skip
        if name == "FRC_Disconnect":
            return {"Communication": name, "ErrorID": 0}
        if name == "FRC_GetStatus":
            return {"Command": name, "ErrorID": 0, "ServoReady": 1, "TPMode": 1,
                    "RMIMotionStatus": int(self.running), "ProgramStatus": 0,
                    "SingleStepMode": 0, "NumberUTool": 10, "NextSequenceID": self.next_seq,
                    "NumberUFrame": 9, "Override": 100}  # fmt: skip
        if name == "FRC_Initialize":
            self.running, self.next_seq = True, 1
            return {"Command": name, "ErrorID": 0, "GroupMask": 1}
        if name == "FRC_Abort":
            self.running = False
            return {"Command": name, "ErrorID": 0}
        if name == "FRC_ReadJointAngles":
            return {"Command": name, "ErrorID": 0, "TimeTag": 7, "JointAngle": self.joints,
                    "Group": 1}  # fmt: skip
        if name == "FRC_JointMotionJRep" and self.running:
            self.joints = dict(packet["JointAngle"])
            self.next_seq += 1
            return {"Instruction": name, "ErrorID": 0, "SequenceID": packet["SequenceID"]}
        return {"Command": "Unknown", "ErrorID": 2556941}  # the manual's unknown-packet reply


class _Session(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        assert isinstance(self.server, _Port)
        controller = self.server.controller
        for line in self.rfile:
            reply = controller.answer(json.loads(line))
            self.wfile.write(json.dumps(reply).encode() + b"\r\n")
            if reply.get("Communication") in ("FRC_Connect", "FRC_Disconnect"):
                return


@pytest.fixture
def manual() -> Iterator[ManualController]:
    controller = ManualController()
    yield controller
    controller.stop()


def test_our_driver_against_a_controller_from_the_manual(manual: ManualController) -> None:
    target = np.array([12.0, -3.0, 4.0, 0.0, -85.0, 6.0])
    with RmiRobot("127.0.0.1", manual.port, timeout_s=1.0) as robot:
        np.testing.assert_allclose(robot.joints_deg(), [0, 0, 0, 0, -90, 0])
        np.testing.assert_allclose(robot.move_joints(target, speed_pct=50), target, atol=1e-4)
        assert robot.describe() == f"FANUC RMI 3.1 at 127.0.0.1:{manual.port}"
        with pytest.raises(DeviceFault) as info:  # a packet this controller does not know
            robot.set_override_pct(40)
        assert info.value.code == 2556941
    names = [
        p.get("Command") or p.get("Instruction") or p.get("Communication") for p in manual.heard
    ]
    assert names[-1] == "FRC_Disconnect" and "FRC_Initialize" in names
