"""The device layer's exception tree.

    DeviceError                      root: anything a device backend raises
    ├── DeviceConfigError            bad URL, unknown scheme, bad option (also a ValueError)
    ├── DeviceClosedError            the device was used after close()
    ├── CommunicationError           the transport failed; a reconnect may help
    │   ├── DeviceConnectionError    cannot connect, peer closed, I/O error
    │   ├── DeviceTimeout            no (complete) reply within the timeout
    │   └── ProtocolError            malformed, truncated or unexpected reply
    ├── DeviceFault                  the device reported an error (``code``, ``message``)
    │   └── FaultLatched             refused: an earlier fault must be cleared by reset()
    ├── MotionAborted                the motion was stopped by abort(); no fault latched
    └── MotionRefused                a command outside its limits was refused; nothing sent
                                     (also a ValueError)

Every error leaving a device's public method carries ``family`` and ``device`` (its name).
Backends translate vendor errors (OSError, socket.timeout, json, pymodbus, serial, GLib) into the
most specific leaf at the boundary with ``raise ... from exc``, so callers never import a vendor
package to catch an error. What a caller can do: fix the configuration (DeviceConfigError), retry
or reconnect (CommunicationError), reset the device (DeviceFault), plan another motion
(MotionRefused).
"""

from __future__ import annotations

__all__ = [
    "CommunicationError",
    "DeviceClosedError",
    "DeviceConfigError",
    "DeviceConnectionError",
    "DeviceError",
    "DeviceFault",
    "DeviceTimeout",
    "FaultLatched",
    "MotionAborted",
    "MotionRefused",
    "ProtocolError",
]


class DeviceError(Exception):
    """Root of every error raised by the device layer. A device's public method stamps the
    errors that leave it with the device's `family` ("robot", "plc", ...) and `device` name
    (drivers.base), so a caller learns which device failed from the error itself."""

    family: str | None = None
    device: str | None = None


class DeviceConfigError(DeviceError, ValueError):
    """A device URL or option is wrong: nothing was opened."""


class DeviceClosedError(DeviceError):
    """The device was used after close() (or before open())."""


class CommunicationError(DeviceError):
    """The transport to the device failed; reconnecting may help."""


class DeviceConnectionError(CommunicationError):
    """Cannot connect, the peer closed the connection, or an I/O error occurred."""


class DeviceTimeout(CommunicationError):
    """No (complete) reply arrived within the timeout."""


class ProtocolError(CommunicationError):
    """The peer sent a malformed, truncated or unexpected reply."""


class DeviceFault(DeviceError):
    """The device reported an error. ``code`` is the device's own error number (0 if none)."""

    def __init__(self, message: str, *, code: int = 0) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


class FaultLatched(DeviceFault):
    """A command was refused because an earlier fault has not been cleared by reset()."""


class MotionAborted(DeviceError):
    """The motion was stopped by ``abort()`` before it reached its target: the robot stands
    where it stopped (known to the controller), and no fault is latched."""


class MotionRefused(DeviceError, ValueError):
    """A command (robot motion, galvo angle) was refused before it left the process."""
