"""The common base of every device: open/close life cycle, context manager, open-device
tracking (tests fail when a device is left open) and a warning when an open device is
garbage-collected, as python-can's ``BusABC`` does.

A backend implements ``_open()`` and ``_close()`` (and its family's private primitives); the
public methods of the family base classes own the policy: validation, timeouts, retries of
read-only requests after a lost connection, logging, fault latching.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import logging
import threading
import warnings
import weakref
from abc import ABC, abstractmethod
from collections.abc import Callable
from types import TracebackType
from typing import TYPE_CHECKING, Any, ClassVar, Self, TypeVar

from drivers.errors import CommunicationError, DeviceClosedError, DeviceConfigError, DeviceError

if TYPE_CHECKING:
    from drivers.trace import TraceChannel
    from drivers.url import DeviceUrl

T = TypeVar("T")

_OPEN: weakref.WeakSet[Device] = weakref.WeakSet()
_OPEN_LOCK = threading.Lock()


def _stamped(method: Callable[..., T]) -> Callable[..., T]:
    """`method` of a device, stamping the DeviceErrors that leave it with the device (the
    innermost device's stamp wins: a fake camera raising for its galvo names the galvo)."""

    @functools.wraps(method)
    def wrapper(self: Device, *args: Any, **kwargs: Any) -> T:
        try:
            return method(self, *args, **kwargs)
        except DeviceError as exc:
            if exc.family is None:
                exc.family, exc.device = self.family, self.name
            raise

    wrapper.__stamped__ = True  # type: ignore[attr-defined]
    return wrapper


def _stamp_public_methods(cls: type) -> None:
    for name, value in list(vars(cls).items()):
        if name.startswith("_") or not inspect.isfunction(value):
            continue
        if not getattr(value, "__stamped__", False):
            setattr(cls, name, _stamped(value))


def open_devices() -> list[Device]:
    """The devices opened in this process and not closed yet (for leak checks)."""
    with _OPEN_LOCK:
        return list(_OPEN)


class Device(ABC):
    """A device of one family (camera, galvo, robot, tracker, plc) behind one backend."""

    family: ClassVar[str] = "device"
    #: the wire trace of this device (drivers.trace), None when off; set before open()
    trace: TraceChannel | None = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        _stamp_public_methods(cls)  # every family's and backend's public methods

    def __init__(self, *, timeout_s: float = 5.0, name: str = "") -> None:
        if not timeout_s > 0:
            raise DeviceConfigError(f"timeout_s must be > 0, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self.name = name or type(self).__name__
        self.log = logging.getLogger(f"rvis.drivers.{self.family}")
        self._is_open = False
        self._lock = threading.RLock()

    # -- life cycle ---------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._is_open

    @property
    def needs_reopen(self) -> bool:
        """The device went away and this object cannot use it again until it is closed and
        opened again (a backend that reconnects by itself never is: False)."""
        return False

    def open(self) -> Self:
        """Connect to the device (idempotent). Returns self."""
        with self._lock:
            if not self._is_open:
                self._open_or_clean_up()
                self._is_open = True
                with _OPEN_LOCK:
                    _OPEN.add(self)
                self.log.debug("%s opened", self.name)
        return self

    def close(self) -> None:
        """Disconnect and release every resource (idempotent, never raises a device error)."""
        with self._lock:
            if not self._is_open:
                return
            self._is_open = False
            with _OPEN_LOCK:
                _OPEN.discard(self)
            try:
                self._close()
            except Exception as exc:  # close must not mask the caller's exception
                self.log.warning("%s: error while closing: %s", self.name, exc)
            self.log.debug("%s closed", self.name)

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_is_open", False):
            warnings.warn(
                f"{type(self).__name__} was not closed; call close() or use it as a context "
                "manager",
                ResourceWarning,
                stacklevel=2,
            )
            with contextlib.suppress(Exception):
                self._close()

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> Self:
        """Build the device from a parsed URL (see drivers.registry); not opened yet."""
        raise DeviceConfigError(f"{cls.__name__} cannot be built from {url.raw}")

    def describe(self) -> str:
        """One line identifying the connected device (model, serial, firmware, ...)."""
        self._check_open()
        return self.name

    # -- helpers for family bases -------------------------------------------------------------
    def _check_open(self) -> None:
        if not self._is_open:
            raise DeviceClosedError(f"{self.name} is not open")

    def _reconnect(self) -> None:
        """Close the transport and open it again (used for safe, read-only retries)."""
        self.log.info("%s: reconnecting", self.name)
        try:
            self._close()
        except Exception as exc:
            self.log.debug("%s: close before reconnect failed: %s", self.name, exc)
        self._open_or_clean_up()

    def _open_or_clean_up(self) -> None:
        """``_open()``; if it fails half-way, release what it had already acquired."""
        try:
            self._open()
        except BaseException:
            with contextlib.suppress(Exception):
                self._close()
            raise

    def _read_retrying(self, request: Callable[[], T]) -> T:
        """Run a read-only request; after a communication error reconnect once and retry.

        Only for requests without side effects: a motion or an output is never repeated."""
        self._check_open()
        with self._lock:
            try:
                return request()
            except CommunicationError as exc:
                self.log.warning("%s: %s; retrying after reconnect", self.name, exc)
                self._reconnect()
                return request()

    @abstractmethod
    def _open(self) -> None:
        """Connect the transport and check the device answers."""

    @abstractmethod
    def _close(self) -> None:
        """Release the transport. May be called on a half-open device."""


_stamp_public_methods(Device)  # open(), describe(): the base's own public methods
