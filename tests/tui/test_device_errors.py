"""The service keeps the last error of each device (app.line.operator.device_of names the
device whose method raised it): attributed through the traceback, also across a re-raise in
another thread and through `raise ... from`, and to nobody when no device raised it."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from app.line.operator import device_of
from drivers.errors import DeviceError, DeviceFault, DeviceTimeout


class Plc:
    def poll(self) -> None:
        raise DeviceTimeout("no reply in 0.2 s")


class Robot:
    def move(self) -> None:
        self._send()

    def _send(self) -> None:
        raise DeviceFault("SRVO-050 Collision Detect Alarm", code=50)


class Watcher:
    """Polls the PLC in its own thread and keeps the error (as the cycle's Withdrawal does)."""

    def __init__(self, plc: Plc) -> None:
        self.plc = plc
        self.error: DeviceError | None = None

    def run(self) -> None:
        try:
            self.plc.poll()
        except DeviceError as exc:
            self.error = exc


def caught(fn: Callable[[], None]) -> BaseException:
    with pytest.raises(DeviceError) as info:
        fn()
    return info.value


def test_the_device_whose_method_raised() -> None:
    plc, robot = Plc(), Robot()
    devices = {"plc": plc, "robot": robot}
    assert device_of(caught(robot.move), devices) == "robot"
    assert device_of(caught(plc.poll), devices) == "plc"
    assert device_of(caught(robot.move), {"plc": plc}) is None  # not one of the devices


def test_an_error_re_raised_from_another_thread_is_the_plcs() -> None:
    plc = Plc()
    watcher = Watcher(plc)
    thread = threading.Thread(target=watcher.run)
    thread.start()
    thread.join()

    def reraise() -> None:
        assert watcher.error is not None
        raise watcher.error

    assert device_of(caught(reraise), {"plc": plc, "robot": Robot()}) == "plc"


def test_through_the_cause_and_not_without_a_device() -> None:
    robot = Robot()

    def wrapped() -> None:
        try:
            robot.move()
        except DeviceFault as exc:
            raise DeviceError("the window failed") from exc

    def nobody() -> None:
        raise DeviceTimeout("the sensor timed out")

    assert device_of(caught(wrapped), {"robot": robot}) == "robot"
    assert device_of(caught(nobody), {"robot": robot}) is None
