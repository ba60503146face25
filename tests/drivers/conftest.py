"""Fixtures for the device tests: a leak check that fails a test leaving a device open, the
`hardware` marker gate, and a small shared world."""

from __future__ import annotations

import os
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


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if os.environ.get("RVIS_HARDWARE") == "1":
        return
    skip = pytest.mark.skip(reason="needs real devices (set RVIS_HARDWARE=1)")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def world() -> StaticWorld:
    return StaticWorld()
