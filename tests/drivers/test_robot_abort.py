"""Robot.abort() during a long move, on every backend: it reaches the controller at once
(<= 0.2 s), the move raises MotionAborted, the robot (the peer's world) stops short of the target,
no fault is latched, and the next motion runs."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack

import numpy as np
import pytest
from numpy.typing import ArrayLike

from drivers import MotionAborted, open_robot
from drivers.robot import Robot
from fakes.world import StaticWorld

START = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
FAR = np.array([60.0, 0.0, 0.0, 0.0, -90.0, 0.0])  # 60 deg of J1 at 10 %: about 3.4 s


class WatchedWorld(StaticWorld):
    """A world that signals when the robot has moved away from where it started."""

    def __init__(self) -> None:
        super().__init__(q_deg=tuple(START))
        self.moving = threading.Event()

    def set_joints_deg(self, q_deg: ArrayLike) -> None:
        super().set_joints_deg(q_deg)
        if np.abs(self.joints_deg() - START).max() > 0.05:
            self.moving.set()


def _url(kind: str, world: WatchedWorld, stack: ExitStack) -> tuple[str, dict[str, object]]:
    if kind == "fake":
        return "fake://", {"world": world, "time_scale": 1.0}
    if kind == "rmi":
        from fakes.rmi_controller import RmiController

        ctrl = stack.enter_context(RmiController(world, time_scale=1.0))
        return f"rmi://127.0.0.1:{ctrl.port}", {}
    from fakes.modbus_robot import ModbusRobotServer

    server = stack.enter_context(ModbusRobotServer(world, time_scale=1.0))
    return f"modbus://127.0.0.1:{server.port}", {"poll_s": 0.01}


@pytest.fixture(params=["fake", "rmi", "modbus"])
def setup(request: pytest.FixtureRequest) -> Iterator[tuple[Robot, WatchedWorld]]:
    world = WatchedWorld()
    with ExitStack() as stack:
        url, options = _url(str(request.param), world, stack)
        robot = stack.enter_context(open_robot(url, timeout_s=1.0, **options))
        yield robot, world


def test_abort_during_a_long_move_stops_the_robot_at_once(
    setup: tuple[Robot, WatchedWorld],
) -> None:
    robot, world = setup
    outcome: list[BaseException | None] = []

    def move() -> None:
        try:
            robot.move_joints(FAR, speed_pct=10)
            outcome.append(None)
        except BaseException as exc:
            outcome.append(exc)

    mover = threading.Thread(target=move)
    mover.start()
    assert world.moving.wait(2.0), "the motion never started"
    t0 = time.monotonic()
    robot.abort()
    elapsed_s = time.monotonic() - t0
    mover.join(2.0)
    assert not mover.is_alive()
    assert elapsed_s <= 0.5  # half the 1 s timeout: not waited for (nor the 3.4 s move)
    assert len(outcome) == 1 and isinstance(outcome[0], MotionAborted)
    stopped = world.joints_deg()
    assert 0.05 < stopped[0] < FAR[0] - 10.0  # short of the target, by far
    assert robot.fault is None  # an abort is not a fault
    status = robot.status()
    assert not status.fault and not status.moving and robot.fault is None
    np.testing.assert_allclose(robot.joints_deg(), stopped, atol=1e-3)  # it stays there
    back = robot.move_joints(START, speed_pct=100)  # and moves again without a reset
    np.testing.assert_allclose(back, START, atol=1e-3)


def test_abort_without_a_motion_is_harmless(setup: tuple[Robot, WatchedWorld]) -> None:
    robot, world = setup
    robot.abort()
    assert world.moves == 0
    target = START + np.array([5.0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(robot.move_joints(target, speed_pct=100), target, atol=1e-3)
    assert robot.fault is None


def test_a_link_lost_during_the_abort_stays_a_fault() -> None:
    """If the controller cannot confirm the stop, the robot's state is unknown: the motion ends
    in a latched communication fault, not in MotionAborted."""
    from drivers import DeviceConnectionError
    from fakes.rmi_controller import RmiController

    world = WatchedWorld()
    with (
        RmiController(world, time_scale=1.0) as ctrl,
        open_robot(f"rmi://127.0.0.1:{ctrl.port}", timeout_s=1.0) as robot,
    ):
        outcome: list[BaseException] = []
        mover = threading.Thread(target=lambda: _move(robot, outcome))
        mover.start()
        assert world.moving.wait(2.0)
        ctrl.fail_next("FRC_Abort", "drop")  # the controller vanishes on receipt
        with pytest.raises(DeviceConnectionError):
            robot.abort()
        mover.join(2.0)
        assert len(outcome) == 1 and isinstance(outcome[0], DeviceConnectionError)
        assert isinstance(robot.fault, DeviceConnectionError)


def _move(robot: Robot, out: list[BaseException]) -> None:
    try:
        robot.move_joints(FAR, speed_pct=10)
    except BaseException as exc:
        out.append(exc)
