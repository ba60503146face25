"""RMI driver against the asyncio fake controller: protocol details and fault handling."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers import (
    DeviceConfigError,
    DeviceConnectionError,
    DeviceFault,
    DeviceTimeout,
    FaultLatched,
    ProtocolError,
)
from drivers.rmi import RMIT_BASE, RmiRobot
from drivers.rmi_errors import INVALID_DESTINATION as ERR_LIMIT
from drivers.rmi_errors import INVALID_OVERRIDE as ERR_VALUE
from fakes.rmi_controller import RmiController
from fakes.world import StaticWorld

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
A = np.array([20.0, 5.0, -5.0, 10.0, -80.0, 30.0])


@pytest.fixture
def ctrl(world: StaticWorld) -> Iterator[RmiController]:
    with RmiController(world, time_scale=0.002) as c:
        yield c


@pytest.fixture
def robot(ctrl: RmiController) -> Iterator[RmiRobot]:
    with RmiRobot("127.0.0.1", ctrl.port, timeout_s=1.0, motion_timeout_s=2.0) as r:
        yield r


def sent(ctrl: RmiController, name: str) -> list[dict[str, object]]:
    return [m for m in ctrl.received if name in m.values()]


def test_handshake_uses_the_session_port_and_consecutive_sequence_ids(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    robot.move_joints(A, speed_pct=100)
    robot.move_joints(HOME, speed_pct=100)
    assert ctrl.received[0] == {"Communication": "FRC_Connect"}
    motions = sent(ctrl, "FRC_JointMotionJRep")
    assert [m["SequenceID"] for m in motions] == [1, 2]
    assert motions[0]["SpeedType"] == "Percent" and motions[0]["TermType"] == "FINE"
    assert sent(ctrl, "FRC_Initialize")
    robot.close()
    assert ctrl.received[-1] == {"Communication": "FRC_Disconnect"}


def test_error_code_from_the_controller_is_a_device_fault(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", ERR_LIMIT)
    with pytest.raises(DeviceFault, match="RMIT-036 Invalid Destination Position") as info:
        robot.move_joints(A, speed_pct=100)
    assert info.value.code == ERR_LIMIT and ERR_LIMIT > RMIT_BASE
    with pytest.raises(FaultLatched):  # no motion after a fault ...
        robot.move_joints(A, speed_pct=100)
    robot.reset()  # ... until a reset
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-3)
    assert [m["SequenceID"] for m in sent(ctrl, "FRC_JointMotionJRep")][-1] == 1


def test_system_fault_during_motion(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", "system_fault")
    with pytest.raises(DeviceFault, match="system fault"):
        robot.move_joints(A, speed_pct=100)
    assert robot.status().fault and ctrl.alarm
    with pytest.raises(FaultLatched):
        robot.move_joints(HOME, speed_pct=100)
    robot.reset()
    assert not ctrl.alarm
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-3)


def test_peer_disconnects_mid_motion(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", "drop")
    with pytest.raises(DeviceConnectionError):
        robot.move_joints(A, speed_pct=100)
    with pytest.raises(FaultLatched):
        robot.move_joints(A, speed_pct=100)
    robot.reset()  # reconnects: the session is gone
    np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-3)


def test_read_reconnects_after_a_lost_session(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_ReadJointAngles", "drop")
    np.testing.assert_allclose(robot.joints_deg(), HOME)  # retried once, transparently
    assert len(sent(ctrl, "FRC_Connect")) == 2


def test_motion_timeout_aborts(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", "mute")
    with pytest.raises(DeviceTimeout):
        robot.move_joints(A, speed_pct=100, timeout_s=0.2)
    assert sent(ctrl, "FRC_Abort")
    assert isinstance(robot.fault, DeviceTimeout)


@pytest.mark.parametrize("mode", ["garble", "truncate"])
def test_malformed_or_truncated_reply_is_a_protocol_error(
    ctrl: RmiController, robot: RmiRobot, mode: str
) -> None:
    ctrl.fail_next("FRC_GetStatus", mode)
    ctrl.fail_next("FRC_ReadJointAngles", mode)
    with pytest.raises(ProtocolError):
        robot._status()  # the primitive: no retry
    robot.reset()
    np.testing.assert_allclose(robot.joints_deg(), HOME)  # public read: retried


def test_terminate_from_controller(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.terminate_sessions()
    np.testing.assert_allclose(robot.joints_deg(), HOME)  # reconnected


def test_cannot_connect_is_a_connection_error() -> None:
    with pytest.raises(DeviceConnectionError):
        RmiRobot("127.0.0.1", 1, timeout_s=0.5).open()


def test_override_scales_the_controllers_motion_time(ctrl: RmiController, robot: RmiRobot) -> None:
    robot.move_joints(A, speed_pct=100)
    robot.set_override_pct(25)
    robot.move_joints(HOME, speed_pct=100)  # the same joint distance back
    assert sent(ctrl, "FRC_SetOverRide") == [{"Command": "FRC_SetOverRide", "Value": 25}]
    full, quarter = ctrl.motion_durations_s
    assert quarter == pytest.approx(4 * full)
    assert ctrl.override_pct == 25 and robot.status().override_pct == 25


def test_override_refused_by_the_controller_is_a_fault_not_a_motion_fault(
    ctrl: RmiController, robot: RmiRobot
) -> None:
    ctrl.fail_next("FRC_SetOverRide", ERR_VALUE)
    with pytest.raises(DeviceFault) as info:
        robot.set_override_pct(30)
    assert info.value.code == ERR_VALUE and ctrl.override_pct == 100
    assert robot.fault is None  # nothing moved: no latch
    with pytest.raises(DeviceConfigError):
        robot.set_override_pct(0)
    assert len(sent(ctrl, "FRC_SetOverRide")) == 1  # the refused value never left the process


def test_override_survives_a_lost_session(ctrl: RmiController, robot: RmiRobot) -> None:
    ctrl.fail_next("FRC_SetOverRide", "drop")
    robot.set_override_pct(60)  # idempotent: reconnected and sent again
    assert ctrl.override_pct == 60
    assert len(sent(ctrl, "FRC_Connect")) == 2


def test_controller_gone_and_back(world: StaticWorld) -> None:
    ctrl = RmiController(world, time_scale=0.002).start()
    try:
        with RmiRobot("127.0.0.1", ctrl.port, timeout_s=0.5, motion_timeout_s=2.0) as robot:
            np.testing.assert_allclose(robot.joints_deg(), HOME)
            port = ctrl.port
            ctrl.close()  # the controller vanishes mid-session
            with pytest.raises(DeviceConnectionError):
                robot.joints_deg()  # the retry's reconnect is refused too
            with pytest.raises(DeviceConnectionError):
                robot.reset()
            ctrl = RmiController(world, time_scale=0.002, port=port).start()
            robot.reset()  # reconnects to the new session
            np.testing.assert_allclose(robot.move_joints(A, speed_pct=100), A, atol=1e-3)
    finally:
        ctrl.close()


@pytest.mark.parametrize("mode", ["mute", "garble", "truncate"])
def test_bad_motion_reply_blocks_motion_until_reset(
    ctrl: RmiController, robot: RmiRobot, mode: str
) -> None:
    ctrl.fail_next("FRC_JointMotionJRep", mode)
    with pytest.raises(DeviceTimeout if mode == "mute" else ProtocolError):
        robot.move_joints(A, speed_pct=100, timeout_s=0.2)
    motions = len(sent(ctrl, "FRC_JointMotionJRep"))
    with pytest.raises(FaultLatched):
        robot.move_joints(HOME, speed_pct=100)
    assert len(sent(ctrl, "FRC_JointMotionJRep")) == motions  # nothing sent
    robot.reset()
    np.testing.assert_allclose(robot.move_joints(HOME, speed_pct=100), HOME, atol=1e-3)
