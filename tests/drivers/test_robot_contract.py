"""Robot contract: one test body per behaviour, run on fake://, the RMI and Modbus peers and a
real controller (``RVIS_ROBOT_URL``), all within the safety profile of tests/drivers/backends.py
(start at home, a small joint box enforced by the driver's guard, 10 % speed and override)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
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
from tests.drivers.backends import HARDWARE, backends, fake_only, real_url, robot_profile

FAST = 0.002  # time compression of the fakes: a 5 deg move at 1 % takes about 6 ms
FaultNext = Callable[[Robot], None]  # the peer fails the next motion with a controller alarm


@dataclass
class Peer:
    """What a fake back end offers beyond the device: its world (the truth) and a fault."""

    world: StaticWorld
    fault_next: FaultNext


@dataclass
class RobotRig:
    robot: Robot
    peer: Peer | None  # None on a real controller

    def truth_deg(self) -> Any:
        """The joints the world holds (fakes), or what the controller reports (hardware)."""
        return self.robot.joints_deg() if self.peer is None else self.peer.world.joints_deg()


def _fake(world: StaticWorld, stack: ExitStack) -> tuple[str, dict[str, Any], FaultNext]:
    def fault(robot: Robot) -> None:
        assert isinstance(robot, FakeRobot)
        robot.inject_fault(50)

    return "fake://", {"world": world, "time_scale": FAST}, fault


def _rmi(world: StaticWorld, stack: ExitStack) -> tuple[str, dict[str, Any], FaultNext]:
    from fakes.rmi_controller import RmiController

    ctrl = stack.enter_context(RmiController(world, time_scale=FAST))
    fault = lambda _: ctrl.fail_next("FRC_JointMotionJRep", "system_fault")  # noqa: E731
    return f"rmi://127.0.0.1:{ctrl.port}", {}, fault


def _modbus(world: StaticWorld, stack: ExitStack) -> tuple[str, dict[str, Any], FaultNext]:
    from fakes.modbus_robot import ModbusRobotServer

    server = stack.enter_context(ModbusRobotServer(world, time_scale=FAST))
    return f"modbus://127.0.0.1:{server.port}", {}, lambda _: server.fault_next_motion(50)


FAKES: dict[str, Callable[[StaticWorld, ExitStack], tuple[str, dict[str, Any], FaultNext]]] = {
    "fake": _fake,
    "rmi": _rmi,
    "modbus": _modbus,
}


@pytest.fixture(params=backends("robot", sorted(FAKES)))
def rig(request: pytest.FixtureRequest, world: StaticWorld) -> Iterator[RobotRig]:
    profile = robot_profile()
    with ExitStack() as stack:
        peer = None
        if request.param == HARDWARE:
            url, options = real_url("robot"), {"timeout_s": 5.0}
        else:
            url, options, fault = FAKES[request.param](world, stack)
            options["timeout_s"] = 2.0
            peer = Peer(world, fault)
        robot = stack.enter_context(open_robot(url, guard=profile.guard(), **options))
        profile.start(robot)
        stack.callback(profile.finish, robot)
        yield RobotRig(robot, peer)


def test_reads_its_joints_at_home(rig: RobotRig) -> None:
    profile = robot_profile()
    q = rig.robot.joints_deg()
    assert q.shape == (6,) and q.dtype == np.float64
    np.testing.assert_allclose(q, profile.home_deg, atol=profile.home_tol_deg)
    np.testing.assert_allclose(q, rig.truth_deg(), atol=1e-3)
    status = rig.robot.status()
    assert status.servo_ready and not status.fault
    assert rig.robot.describe()


def test_moves_inside_the_box_and_comes_back(rig: RobotRig) -> None:
    profile, robot = robot_profile(), rig.robot
    first = profile.inside([0.6, 0.4, -0.4, 0.8, 0.6, 1.0])
    reached = robot.move_joints(first, speed_pct=profile.speed_pct)
    np.testing.assert_allclose(reached, first, atol=0.01)
    np.testing.assert_allclose(rig.truth_deg(), first, atol=0.01)
    second = profile.inside([-0.6, 0, 0, 0, 0, -0.5])
    np.testing.assert_allclose(
        robot.move_joints(second, speed_pct=profile.speed_pct), second, atol=0.01
    )
    home = robot.move_joints(profile.home_deg, speed_pct=profile.speed_pct)
    np.testing.assert_allclose(home, profile.home_deg, atol=0.01)
    assert robot.fault is None and not robot.status().fault


def test_refused_motion_sends_nothing(rig: RobotRig) -> None:
    profile, robot = robot_profile(), rig.robot
    before, moves = rig.truth_deg(), None if rig.peer is None else rig.peer.world.moves
    with pytest.raises(MotionRefused, match="J2="):
        robot.move_joints([0, 140, 0, 0, 0, 0], speed_pct=profile.speed_pct)
    with pytest.raises(MotionRefused):
        robot.move_joints([0, 0, 0, 0, np.nan, 0], speed_pct=profile.speed_pct)
    one_joint_out = profile.inside([0] * 6) + np.array([0, 0, 0, 0, 0, 1.5 * profile.box_deg])
    for target in (one_joint_out, profile.inside([0] * 6) - 2.0 * profile.box_deg):
        with pytest.raises(MotionRefused, match="keep-in"):
            robot.move_joints(target, speed_pct=1)
    with pytest.raises(MotionRefused, match="speed"):
        robot.move_joints(profile.inside([0.1, 0, 0, 0, 0, 0]), speed_pct=50)
    np.testing.assert_allclose(rig.truth_deg(), before, atol=1e-3)
    if rig.peer is not None:
        assert rig.peer.world.moves == moves
    assert robot.fault is None  # a refusal is not a fault


def test_closed_robot_refuses_everything(rig: RobotRig) -> None:
    robot = rig.robot
    robot.close()
    robot.close()  # idempotent
    with pytest.raises(DeviceClosedError):
        robot.joints_deg()
    with pytest.raises(DeviceClosedError):
        robot.move_joints(robot_profile().home_deg)


@pytest.mark.parametrize("bad", [0, 101, -20, 50.5, True, "50", None])
def test_override_outside_1_to_100_is_refused(rig: RobotRig, bad: object) -> None:
    with pytest.raises(DeviceConfigError, match=r"1\.\.100"):
        rig.robot.set_override_pct(bad)  # type: ignore[arg-type]


def test_speed_override(rig: RobotRig) -> None:
    robot, profile = rig.robot, robot_profile()
    if robot.describe().startswith("FANUC Modbus"):  # the TP mailbox has no override register
        with pytest.raises(DeviceConfigError, match="no speed override"):
            robot.set_override_pct(5)
        return
    robot.set_override_pct(5)
    assert robot.status().override_pct == 5
    robot.set_override_pct(np.int64(profile.override_pct))  # type: ignore[arg-type]
    assert robot.status().override_pct == profile.override_pct


def _latch_by_a_controller_alarm(rig: RobotRig) -> None:
    """A motion the controller stops with an alarm: the driver latches the fault."""
    peer = fake_only(rig.peer, "controller alarm")
    peer.fault_next(rig.robot)
    with pytest.raises(DeviceError):
        rig.robot.move_joints(robot_profile().inside([0.5, 0, 0, 0, 0, 0]), speed_pct=10)


def test_latched_fault_blocks_motion_until_reset(rig: RobotRig) -> None:
    _latch_by_a_controller_alarm(rig)
    target = robot_profile().inside([0.4, 0, 0, 0, 0, 0])
    with pytest.raises(FaultLatched):
        rig.robot.move_joints(target, speed_pct=10)
    rig.robot.reset()
    np.testing.assert_allclose(rig.robot.move_joints(target, speed_pct=10), target, atol=0.01)


def test_override_is_not_a_motion_so_a_fault_does_not_block_it(rig: RobotRig) -> None:
    if rig.robot.describe().startswith("FANUC Modbus"):
        pytest.skip("the TP mailbox has no override register")
    _latch_by_a_controller_alarm(rig)
    rig.robot.set_override_pct(7)
    assert rig.robot.status().override_pct == 7
    rig.robot.reset()


def test_fake_override_scales_the_motion_time(world: StaticWorld) -> None:
    with FakeRobot(world, time_scale=FAST) as robot:
        robot.move_joints([5, 0, 0, 0, -90, 0], speed_pct=100)
        robot.set_override_pct(25)
        robot.move_joints([0, 0, 0, 0, -90, 0], speed_pct=100)
        full, quarter = robot.motion_durations_s
        assert quarter == pytest.approx(4 * full)
