"""Fixtures for the device tests: a leak check that fails a test leaving a device open, and a
small shared world. Real devices are one more back end of each contract suite
(tests/drivers/backends.py: ``RVIS_<FAMILY>_URL``, the ``hardware`` marker, the safety
profile)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from drivers.base import open_devices
from fakes.world import StaticWorld


@pytest.fixture(autouse=True)
def _no_device_left_open() -> Iterator[None]:
    before = set(map(id, open_devices()))
    yield
    leaked = [d for d in open_devices() if id(d) not in before]
    for device in leaked:
        device.close()
    assert not leaked, f"test left devices open: {[d.name for d in leaked]}"


@pytest.fixture
def world() -> StaticWorld:
    return StaticWorld()
