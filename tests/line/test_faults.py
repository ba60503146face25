"""Device faults in a window through the sweep sensor: a camera that times out and a galvo DAC
that reports an SCPI error put the service in FAULT with the cause, the PLC fault bit set, and
no motion until a reset; the robot comes home in the next window after it. A frame lost once is
re-triggered and the sweep completes."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from app.config.line import SweepSettings
from app.line.measure import SweepSensor
from app.line.states import State
from drivers.errors import DeviceConnectionError, DeviceTimeout
from drivers.robot import FloatArray
from fakes.cell import SimulatedCell
from fakes.devices import FakeCamera, FakeGalvo, FakeRobot
from fakes.world import StaticWorld
from tests.line.helpers import Line, make_line
from vision.sensor_model import default_sensor_model


class DeadCamera(FakeCamera):
    """Never delivers a frame (a cable pulled)."""

    def _trigger(self) -> None:
        pass

    def _grab(self, timeout_s: float) -> object:  # type: ignore[override]
        raise DeviceTimeout(f"{self.name}: no frame within {timeout_s:g} s")


class LosingCamera(FakeCamera):
    """Loses the frame of its first trigger only."""

    lost = 0

    def _trigger(self) -> None:
        if self.lost == 0:
            self.lost += 1
            return
        super()._trigger()


class ErrorGalvo(FakeGalvo):
    """The DAC answers every command with an SCPI error."""

    def _set_volts(self, volts: float) -> None:
        self._queue.append((-350, "Queue overflow"))


@pytest.fixture()
def opened() -> Iterator[list[FakeCamera | FakeGalvo]]:
    devices: list[FakeCamera | FakeGalvo] = []
    yield devices
    for d in devices:
        d.close()


def _sweep(
    camera_cls: type[FakeCamera], galvo_cls: type[FakeGalvo], opened: list[FakeCamera | FakeGalvo]
) -> Callable[[SimulatedCell], SweepSensor]:
    def build(cell: SimulatedCell) -> SweepSensor:
        galvo = galvo_cls()
        galvo.open()
        camera = camera_cls(cell, galvo=galvo)
        camera.open()
        opened.extend([camera, galvo])
        return SweepSensor(camera, galvo, default_sensor_model(), SweepSettings(n_frames=4))

    return build


@pytest.mark.parametrize(
    ("camera_cls", "galvo_cls", "cause"),
    [(DeadCamera, FakeGalvo, "DeviceTimeout"), (FakeCamera, ErrorGalvo, "DAC error -350")],
)
def test_a_sensor_device_fault_in_a_window(
    tmp_path: Path,
    opened: list[FakeCamera | FakeGalvo],
    camera_cls: type[FakeCamera],
    galvo_cls: type[FakeGalvo],
    cause: str,
) -> None:
    ln: Line = make_line(tmp_path, sensor=_sweep(camera_cls, galvo_cls, opened))
    try:
        ln.start()
        alarm = ln.wait(lambda e: e["event"] == "alarm")
        assert alarm["code"] == "device_fault" and cause in alarm["message"]
        assert ln.service.state == State.FAULT
        assert ln.plc.received.fault and not ln.plc.received.done
        moves = len(ln.robot.motion_durations_s)
        assert moves == 1  # it was moved to the sphere, then the sensor failed
        ln.plc.wait_edges(2)
        assert len(ln.robot.motion_durations_s) == moves  # no motion until reset
        assert ln.service.store.counts() == {"ok": 0, "rejected": 0}
        assert ln.service.request("reset", uid=1).result(10)["ok"]
        report = ln.wait(lambda e: e["event"] == "window")
        assert report["note"] == "robot brought home"
        assert ln.service.measurer.at_home()
    finally:
        ln.close()


def test_a_frame_lost_once_is_retriggered(opened: list[FakeCamera | FakeGalvo]) -> None:
    world = StaticWorld()
    galvo = FakeGalvo()
    galvo.open()
    camera = LosingCamera(world, galvo=galvo)
    camera.open()
    opened += [camera, galvo]
    sensor = SweepSensor(
        camera, galvo, default_sensor_model(), SweepSettings(n_frames=3, grab_timeout_s=0.01)
    )
    frames, commands = sensor.grab_sweep()
    assert camera.lost == 1 and frames.shape[0] == 3 and len(commands) == 3


class DisconnectingRobot(FakeRobot):
    """The controller connection drops half-way through the first move."""

    dropped = False

    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None:
        if not self.dropped:
            self.dropped = True
            start = self.world.joints_deg()
            self.world.set_joints_deg(start + 0.5 * (q_deg - start))
            raise DeviceConnectionError(f"{self.name}: connection reset by peer")
        super()._move(q_deg, speed_pct, timeout_s)


def test_a_robot_disconnect_mid_move_is_a_fault_and_the_robot_comes_home_after_reset(
    tmp_path: Path,
) -> None:
    ln = make_line(tmp_path, robot_class=DisconnectingRobot)
    try:
        ln.start()
        alarm = ln.wait(lambda e: e["event"] == "alarm")
        assert (
            "DeviceConnectionError" in alarm["message"] and "connection reset" in alarm["message"]
        )
        assert ln.service.state == State.FAULT and ln.plc.received.fault
        assert not ln.service.measurer.at_home()  # stopped half-way
        assert ln.robot.fault is not None  # the driver latched it too
        ln.plc.wait_edges(2)
        assert ln.robot.motion_durations_s == []
        assert ln.service.request("reset", uid=1).result(10)["ok"]
        report = ln.wait(lambda e: e["event"] == "window")
        assert report["note"] == "robot brought home" and ln.service.measurer.at_home()
        assert ln.wait(lambda e: e["event"] == "window")["measured"] == 1
    finally:
        ln.close()
