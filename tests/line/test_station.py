"""The station opens every device from its URL (fake:// on a world), with the safety guard on
the robot, closes them all, and closes what it had opened when one device fails."""

from __future__ import annotations

import pytest

from app.line.station import Station
from drivers.base import open_devices
from drivers.errors import DeviceConfigError, MotionRefused
from drivers.safety import JointLimits, SafetyGuard
from fakes.world import StaticWorld

URLS = {f: "fake://" for f in ("plc", "robot", "galvo", "camera", "tracker")}


def test_open_every_device_from_urls_and_close_them_all() -> None:
    world = StaticWorld()
    before = len(open_devices())
    limits = JointLimits((-10, -10, -10, -10, -100, -10), (10, 10, 10, 10, 10, 10))
    options = {f: {"world": world} for f in URLS}
    with Station.open(URLS, guard=SafetyGuard(limits=limits), options=options) as st:
        assert set(st.devices()) == set(URLS)
        assert all(d.is_open for d in st.devices().values())
        assert st.camera is not None and st.camera.galvo is st.galvo  # type: ignore[attr-defined]
        with pytest.raises(MotionRefused):  # the guard given is the robot's
            st.robot.move_joints([20.0, 0, 0, 0, -90, 0])
    assert len(open_devices()) == before


def test_a_device_that_fails_to_open_closes_the_others() -> None:
    before = len(open_devices())
    options = {"robot": {"world": StaticWorld()}, "plc": {}}
    with pytest.raises(DeviceConfigError):  # the camera's fake needs a world
        Station.open({"plc": "fake://", "robot": "fake://", "camera": "fake://"}, options=options)
    assert len(open_devices()) == before
