"""The simulated cell wired into the device registry: `fake://` URLs open the in-process fakes
(fakes.devices). The application calls `register_fakes()` where it opens devices from a cell
file (the default cell's devices are all `fake://`); drivers/ itself names nothing of fakes/."""

from __future__ import annotations

from drivers.registry import register_backend

FAKE_BACKENDS = {
    "camera": "fakes.devices:FakeCamera",
    "galvo": "fakes.devices:FakeGalvo",
    "robot": "fakes.devices:FakeRobot",
    "tracker": "fakes.devices:FakeTracker",
    "plc": "fakes.devices:FakePlc",
}


def register_fakes() -> None:
    """`fake://` for every device family (idempotent)."""
    for family, target in FAKE_BACKENDS.items():
        register_backend(family, "fake", target)
