"""Robot contract: written once, run on every backend (fake://, RMI peer, Modbus peer)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from typing import Any

import numpy as np
import pytest

from drivers import (
    DeviceClosedError,
    DeviceConfigError,
    DeviceError,
    FaultLatched,
    MotionRefused,
    open_robot,
)
from drivers.robot import Robot
from fakes.devices import FakeRobot
from fakes.world import StaticWorld

FAST = 0.002  # time compression: a 90 deg move at 100 % takes about 1 ms


FaultNext = Callable[[Robot], None]  # the peer fails the next motion with a controller alarm


def _fake(world: StaticWorld, stack: ExitStack) -> tuple[str, FaultNext]:
    def fault(robot: Robot) -> None:
        assert isinstance(robot, FakeRobot)
        robot.inject_fault(50)

    return "fake://", fault


def _rmi(world: StaticWorld, stack: ExitStack) -> tuple[str, FaultNext]:
    from fakes.rmi_controller import RmiController

    ctrl = stack.enter_context(RmiController(world, time_scale=FAST))
    return f"rmi://127.0.0.1:{ctrl.port}", lambda _: ctrl.fail_next(
        "FRC_JointMotionJRep", "system_fault"
    )


def _modbus(world: StaticWorld, stack: ExitStack) -> tuple[str, FaultNext]:
    from fakes.modbus_robot import ModbusRobotServer

    server = stack.enter_context(ModbusRobotServer(world, time_scale=FAST))
    return f"modbus://127.0.0.1:{server.port}", lambda _: server.fault_next_motion(50)


BACKENDS: dict[str, Callable[[StaticWorld, ExitStack], tuple[str, FaultNext]]] = {
    "fake": _fake,
    "rmi": _rmi,
    "modbus": _modbus,
}


@pytest.fixture(params=sorted(BACKENDS))
def robot_and_fault(
    request: pytest.FixtureRequest, world: StaticWorld
) -> Iterator[tuple[Robot, FaultNext]]:
    with ExitStack() as stack:
        url, fault = BACKENDS[request.param](world, stack)
        options: dict[str, Any] = {"world": world, "time_scale": FAST} if url == "fake://" else {}
        dev = stack.enter_context(open_robot(url, timeout_s=2.0, **options))
        yield dev, fault


@pytest.fixture
def robot(robot_and_fault: tuple[Robot, FaultNext]) -> Robot:
    return robot_and_fault[0]


def _latch_by_a_controller_alarm(robot: Robot, fault_next: FaultNext) -> None:
    """A motion the controller stops with an alarm: the driver latches the fault."""
    fault_next(robot)
    with pytest.raises(DeviceError):
        robot.move_joints([20, 0, 0, 0, -90, 0], speed_pct=100)


def test_reads_the_worlds_joints(robot: Robot, world: StaticWorld) -> None:
    np.testing.assert_allclose(robot.joints_deg(), world.joints_deg(), atol=1e-3)
    assert robot.status().servo_ready
    assert robot.describe()


def test_moves_the_worlds_robot(robot: Robot, world: StaticWorld) -> None:
    target = np.array([30.0, 10.0, -20.0, 45.0, -60.0, 90.0])
    reached = robot.move_joints(target, speed_pct=100)
    np.testing.assert_allclose(reached, target, atol=1e-3)
    np.testing.assert_allclose(world.joints_deg(), target, atol=1e-3)
    second = np.array([-30.0, 0.0, 0.0, 0.0, -90.0, 0.0])
    np.testing.assert_allclose(robot.move_joints(second, speed_pct=50), second, atol=1e-3)


def test_refused_motion_sends_nothing(robot: Robot, world: StaticWorld) -> None:
    before = world.moves
    with pytest.raises(MotionRefused, match="J2="):
        robot.move_joints([0, 140, 0, 0, 0, 0])
    with pytest.raises(MotionRefused):
        robot.move_joints([0, 0, 0, 0, np.nan, 0])
    assert world.moves == before
    assert robot.fault is None  # a refusal is not a fault


def test_closed_robot_refuses_everything(robot: Robot) -> None:
    robot.close()
    robot.close()  # idempotent
    with pytest.raises(DeviceClosedError):
        robot.joints_deg()
    with pytest.raises(DeviceClosedError):
        robot.move_joints([0, 0, 0, 0, -90, 0])


def test_latched_fault_blocks_motion_until_reset(
    robot_and_fault: tuple[Robot, FaultNext],
) -> None:
    robot, fault_next = robot_and_fault
    _latch_by_a_controller_alarm(robot, fault_next)
    with pytest.raises(FaultLatched):
        robot.move_joints([10, 0, 0, 0, -90, 0], speed_pct=100)
    robot.reset()
    robot.move_joints([10, 0, 0, 0, -90, 0], speed_pct=100)


@pytest.mark.parametrize("bad", [0, 101, -20, 50.5, True, "50", None])
def test_override_outside_1_to_100_is_refused(robot: Robot, bad: object) -> None:
    with pytest.raises(DeviceConfigError, match=r"1\.\.100"):
        robot.set_override_pct(bad)  # type: ignore[arg-type]


def test_speed_override(robot_and_fault: tuple[Robot, FaultNext]) -> None:
    robot, fault_next = robot_and_fault
    if robot.describe().startswith("FANUC Modbus"):  # the TP mailbox has no override register
        with pytest.raises(DeviceConfigError, match="no speed override"):
            robot.set_override_pct(50)
        return
    robot.set_override_pct(40)
    assert robot.status().override_pct == 40
    _latch_by_a_controller_alarm(robot, fault_next)
    robot.set_override_pct(np.int64(20))  # type: ignore[arg-type]  # not a motion
    assert robot.status().override_pct == 20


def test_fake_override_scales_the_motion_time(world: StaticWorld) -> None:
    with FakeRobot(world, time_scale=FAST) as robot:
        robot.move_joints([20, 0, 0, 0, -90, 0], speed_pct=100)
        robot.set_override_pct(25)
        robot.move_joints([0, 0, 0, 0, -90, 0], speed_pct=100)
        full, quarter = robot.motion_durations_s
        assert quarter == pytest.approx(4 * full)
