"""The robot family: read joints, move in joint space, abort, reset, status.

Joint angles are FANUC controller (pendant) angles J1..J6 in degrees, shape (6,). The base class
owns the policy; a backend implements the private primitives:

- ``_read_joints() -> (6,)``          read-only; retried once after a reconnect
- ``_status() -> RobotStatus``        read-only; retried once after a reconnect
- ``_move(q_deg, speed_pct, timeout_s)``  one joint move, returns when the robot has arrived
- ``_abort()``                       called from any thread WITHOUT the device lock, while
                                      ``_move`` may be running in another thread: it must reach
                                      the controller at once and make ``_move`` return (raise)
- ``_reset()``
- ``_set_override(override_pct)``    optional; the controller's general speed override

Policy: every target goes through the SafetyGuard first (joint limits, envelope, path); a motion
is never retried; any fault or communication error during a motion latches a fault, and every
further motion raises FaultLatched until ``reset()`` succeeds. Backends that receive unsolicited
fault messages call ``_latch_fault``. ``abort()`` does not wait for the motion in progress (which
holds the device lock until it ends): it stops the robot at once, and the interrupted
``move_joints`` raises MotionAborted (not a fault: the robot stands still where it stopped).
"""

from __future__ import annotations

import threading
from abc import abstractmethod
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from drivers.base import Device
from drivers.errors import (
    CommunicationError,
    DeviceConfigError,
    DeviceError,
    DeviceFault,
    FaultLatched,
    MotionAborted,
)
from drivers.safety import SafetyGuard

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RobotStatus:
    """What the controller says about itself."""

    servo_ready: bool
    moving: bool
    fault: bool
    error_code: int = 0
    detail: str = ""
    override_pct: int | None = None  # the general speed override, None if the backend has none


class Robot(Device):
    """A robot controller moving the M-710iC/50 in controller joint angles [deg]."""

    family = "robot"

    def __init__(
        self,
        *,
        guard: SafetyGuard | None = None,
        timeout_s: float = 5.0,
        motion_timeout_s: float = 120.0,
        name: str = "",
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        if not motion_timeout_s > 0:
            raise DeviceConfigError(f"motion_timeout_s must be > 0, got {motion_timeout_s!r}")
        self.guard = guard if guard is not None else SafetyGuard()
        self.motion_timeout_s = float(motion_timeout_s)
        self._fault: DeviceError | None = None
        self._abort_requested = threading.Event()

    @property
    def fault(self) -> DeviceError | None:
        """The latched fault, or None."""
        return self._fault

    def joints_deg(self) -> FloatArray:
        """Current controller joint angles J1..J6 [deg], shape (6,)."""
        q = self._read_retrying(self._read_joints)
        return np.asarray(q, dtype=np.float64).reshape(6)

    def status(self) -> RobotStatus:
        status = self._read_retrying(self._status)
        if status.fault and self._fault is None:
            detail = status.detail or "controller fault"
            self._latch_fault(FaultLatched(detail, code=status.error_code))
        return status

    def move_joints(
        self, q_deg: ArrayLike, *, speed_pct: float = 10.0, timeout_s: float | None = None
    ) -> FloatArray:
        """Move to ``q_deg`` (controller angles [deg]) and return the joints reached.

        Raises MotionRefused (nothing sent: outside the limits or the envelope, or faster than
        the guard's ``max_speed_pct``), FaultLatched (reset first), DeviceFault, or a
        CommunicationError (the fault is latched: the state of the robot is unknown), or
        MotionAborted when ``abort()`` stopped it (no fault latched)."""
        self._check_open()
        speed_pct = self.guard.check_speed(speed_pct)
        if self._fault is not None:
            raise FaultLatched(f"{self.name}: fault not reset: {self._fault}")
        target = self.guard.check(q_deg, self.joints_deg())
        timeout = self.motion_timeout_s if timeout_s is None else float(timeout_s)
        self.log.info("%s: move to %s at %g %%", self.name, np.round(target, 4), speed_pct)
        with self._lock:
            self._abort_requested.clear()
            try:
                self._move(target, float(speed_pct), timeout)
            except DeviceError as exc:
                # the controller reported the stop: a known state; a lost link stays a fault
                if self._abort_requested.is_set() and isinstance(exc, DeviceFault):
                    raise MotionAborted(f"{self.name}: motion aborted") from exc
                self._latch_fault(exc)
                raise
        return self.joints_deg()

    def set_override_pct(self, override_pct: int) -> None:
        """Set the controller's general speed override [%], an integer in 1..100: every later
        motion runs at ``speed_pct`` x ``override_pct`` / 100. Not a motion, so allowed with a
        latched fault; idempotent, so retried once after a reconnect. DeviceConfigError for a
        value outside 1..100 (nothing sent) or a backend without an override."""
        self._check_open()
        valid_type = isinstance(override_pct, int | np.integer) and not isinstance(
            override_pct, bool
        )
        if not (valid_type and 1 <= override_pct <= 100):
            raise DeviceConfigError(
                f"override_pct must be an integer in 1..100, got {override_pct!r}"
            )
        self._read_retrying(lambda: self._set_override(int(override_pct)))
        self.log.info("%s: speed override %d %%", self.name, override_pct)

    def abort(self) -> None:
        """Stop the current motion at once (the robot decelerates); callable from any thread.

        Does not wait for the motion in progress: the stop reaches the controller immediately
        and the interrupted ``move_joints`` raises MotionAborted. Without a motion in progress it
        is a plain stop command."""
        self._check_open()
        self._abort_requested.set()
        self.log.warning("%s: abort", self.name)
        self._abort()

    def reset(self) -> None:
        """Clear the controller's alarms and the latched fault; reconnects if needed."""
        self._check_open()
        with self._lock:
            try:
                self._reset()
            except CommunicationError:
                self._reconnect()
                self._reset()
            self._fault = None
        self.log.info("%s: reset", self.name)

    def _latch_fault(self, exc: DeviceError) -> None:
        if self._fault is None:
            self.log.error("%s: fault latched: %s", self.name, exc)
            self._fault = exc

    @abstractmethod
    def _read_joints(self) -> ArrayLike: ...

    @abstractmethod
    def _status(self) -> RobotStatus: ...

    @abstractmethod
    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None: ...

    def _set_override(self, override_pct: int) -> None:
        raise DeviceConfigError(f"{self.name}: this backend has no speed override")

    @abstractmethod
    def _abort(self) -> None: ...

    @abstractmethod
    def _reset(self) -> None: ...
