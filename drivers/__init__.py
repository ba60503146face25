"""Device interfaces (camera, galvo, robot, tracker, PLC) and their real backends, selected by
URL. Drivers move joints and grab frames; they know no kinematics (no calib/, vision/, app/).

    from drivers import open_robot, SafetyGuard
    with open_robot("rmi://10.0.0.5:16001", guard=SafetyGuard()) as robot:
        robot.move_joints(q_deg, speed_pct=20)

Importing this package imports no vendor library (pymodbus, serial, gi): a backend is imported
when its URL scheme is opened (drivers.registry).
"""

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
from drivers.safety import CartesianBox, Envelope, JointBox, JointLimits, SafetyGuard

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
