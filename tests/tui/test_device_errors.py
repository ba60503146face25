"""The service keeps the last error of each device (app.line.operator.device_of names the
device that raised it): every error leaving a device's public method carries the device's
family and name (drivers.base stamps them), also when it is re-raised in another thread or
wrapped by `raise ... from`, and nobody is named when no device raised it."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import pytest

from app.line.status import device_of
from drivers.errors import DeviceError, DeviceFault, DeviceTimeout
from fakes.devices import FakePlc, FakeRobot
from fakes.world import StaticWorld


class DeadPlc(FakePlc):
    """A PLC that never answers."""

    def _read_input_words(self) -> tuple[int, int]:
        raise DeviceTimeout("no reply in 0.2 s")


class Watcher:
    """Polls the PLC in its own thread and keeps the error (as the cycle's Withdrawal does)."""

    def __init__(self, plc: FakePlc) -> None:
        self.plc = plc
        self.error: DeviceError | None = None

    def run(self) -> None:
        try:
            self.plc.poll()
        except DeviceError as exc:
            self.error = exc


def caught(fn: Callable[[], object]) -> BaseException:
    with pytest.raises(DeviceError) as info:
        fn()
    return info.value


@pytest.fixture
def robot() -> Iterator[FakeRobot]:
    r = FakeRobot(StaticWorld(), name="rmi://10.0.0.5").open()
    r.inject_fault(50, "SRVO-050 Collision Detect Alarm")
    yield r
    r.close()


@pytest.fixture
def plc() -> Iterator[DeadPlc]:
    p = DeadPlc(name="plc+modbus://10.0.0.2").open()
    yield p
    p.close()


def test_the_device_whose_method_raised(robot: FakeRobot, plc: DeadPlc) -> None:
    devices = {"plc": plc, "robot": robot}
    moved = caught(lambda: robot.move_joints([0, 0, 0, 0, -80, 0], speed_pct=10))
    assert isinstance(moved, DeviceFault)
    assert (moved.family, moved.device) == ("robot", "rmi://10.0.0.5")
    assert device_of(moved, devices) == "robot"
    assert device_of(caught(plc.poll), devices) == "plc"
    assert device_of(moved, {"plc": plc}) is None  # not one of the devices


def test_an_error_re_raised_from_another_thread_is_the_plcs(robot: FakeRobot, plc: DeadPlc) -> None:
    watcher = Watcher(plc)
    thread = threading.Thread(target=watcher.run)
    thread.start()
    thread.join()

    def reraise() -> None:
        assert watcher.error is not None
        raise watcher.error

    assert device_of(caught(reraise), {"plc": plc, "robot": robot}) == "plc"


def test_through_the_cause_and_not_without_a_device(robot: FakeRobot) -> None:
    def wrapped() -> None:
        try:
            robot.move_joints([0, 0, 0, 0, -80, 0], speed_pct=10)
        except DeviceFault as exc:
            raise DeviceError("the window failed") from exc

    def nobody() -> None:
        raise DeviceTimeout("the sensor timed out")

    assert device_of(caught(wrapped), {"robot": robot}) == "robot"
    assert device_of(caught(nobody), {"robot": robot}) is None
