"""Device interfaces (camera, galvo, robot, tracker, PLC) and their real backends, selected by
URL. Drivers move joints and grab frames; they know no kinematics (no calib/, vision/, app/).

    from drivers import open_robot, SafetyGuard
    with open_robot("rmi://10.0.0.5:16001", guard=SafetyGuard()) as robot:
        robot.move_joints(q_deg, speed_pct=20)

Importing this package imports no vendor library (pymodbus, serial, gi): a backend is imported
when its URL scheme is opened (drivers.registry). Nor does it import numpy: the safety guard's
names (drivers.safety) load on first use, so that a light module of the package
(drivers.clock, drivers.errors, drivers.url) costs no numerics to whoever imports it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from drivers.errors import (
    CommunicationError,
    DeviceClosedError,
    DeviceConfigError,
    DeviceConnectionError,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    FaultLatched,
    MotionAborted,
    MotionRefused,
    ProtocolError,
)
from drivers.registry import (
    create_device,
    open_camera,
    open_device,
    open_galvo,
    open_plc,
    open_robot,
    open_tracker,
    parse_url,
)

if TYPE_CHECKING:
    from drivers.safety import CartesianBox, Envelope, JointBox, JointLimits, SafetyGuard

_SAFETY = ("CartesianBox", "Envelope", "JointBox", "JointLimits", "SafetyGuard")


def __getattr__(name: str) -> Any:
    """The safety guard's names, from drivers.safety when first asked for."""
    if name in _SAFETY:
        return getattr(importlib.import_module("drivers.safety"), name)
    raise AttributeError(f"module 'drivers' has no attribute {name!r}")


__all__ = [
    "CartesianBox",
    "CommunicationError",
    "DeviceClosedError",
    "DeviceConfigError",
    "DeviceConnectionError",
    "DeviceError",
    "DeviceFault",
    "DeviceTimeout",
    "Envelope",
    "FaultLatched",
    "JointBox",
    "JointLimits",
    "MotionAborted",
    "MotionRefused",
    "ProtocolError",
    "SafetyGuard",
    "create_device",
    "open_camera",
    "open_device",
    "open_galvo",
    "open_plc",
    "open_robot",
    "open_tracker",
    "parse_url",
]
