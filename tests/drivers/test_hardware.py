"""Read-only checks against real devices: run with RVIS_HARDWARE=1 and the device URLs in
RVIS_<FAMILY>_URL (e.g. RVIS_ROBOT_URL=rmi://10.0.0.5:16001). Never moves the robot."""

from __future__ import annotations

import os

import pytest

from drivers import open_device

pytestmark = pytest.mark.hardware


@pytest.mark.parametrize("family", ["camera", "galvo", "robot", "tracker", "plc"])
def test_device_answers(family: str) -> None:
    url = os.environ.get(f"RVIS_{family.upper()}_URL")
    if not url:
        pytest.skip(f"RVIS_{family.upper()}_URL not set")
    with open_device(family, url) as device:
        assert device.describe()
