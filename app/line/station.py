"""The station: every device of the cell opened from its URL (drivers.registry), with the
safety guard on the robot, and closed together.

    with Station.open(cfg.devices, guard=cell_guard(cfg)) as st: ...
    Station(robot=..., plc=..., camera=..., galvo=...)   # from devices opened elsewhere (tests)

`options` passes backend keyword arguments per family (e.g. `world=` for `fake://`). A device
that fails to open closes those opened before it and the error propagates (a typed
drivers.errors.DeviceError). With `defer_unreachable=True` (the service, `rvis run`), a device
that is configured right but cannot be reached (any DeviceError but DeviceConfigError) is kept
built and unopened instead: `unreachable` names it with its error, the others are open, and
`open_unreachable()` tries it again (the service's retries with back-off). A wrong URL or
option is still a DeviceConfigError at once. `reopen_lost()` closes and opens again a device
lost while running (a camera that went away: the operator's reset).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Self, cast

from drivers.base import Device
from drivers.camera import Camera
from drivers.errors import DeviceConfigError, DeviceError
from drivers.galvo import Galvo
from drivers.plc import Plc
from drivers.registry import create_device
from drivers.robot import Robot
from drivers.safety import SafetyGuard
from drivers.trace import WireTrace
from drivers.tracker import Tracker
from fakes.wiring import register_fakes

#: Opened in this order (closed in the reverse one): the PLC first, so a fault can be signalled.
ORDER = ("plc", "robot", "galvo", "camera", "tracker")


@dataclass
class Station:
    """The devices of one cell; `camera`, `galvo` and `tracker` are optional (a geometric
    sensor needs neither camera nor galvo)."""

    robot: Robot
    plc: Plc
    camera: Camera | None = None
    galvo: Galvo | None = None
    tracker: Tracker | None = None
    #: family -> the URL each device was opened with (the operator's terminal shows them)
    urls: dict[str, str] = field(default_factory=dict)
    #: the wire trace the devices write to (drivers.trace.WireTrace), closed with them
    trace: WireTrace | None = None
    #: family -> the error of a device built but not opened (`defer_unreachable`), in ORDER
    unreachable: dict[str, DeviceError] = field(default_factory=dict)

    @classmethod
    def open(
        cls,
        urls: Mapping[str, str],
        *,
        guard: SafetyGuard | None = None,
        options: Mapping[str, Mapping[str, Any]] | None = None,
        trace: WireTrace | None = None,
        defer_unreachable: bool = False,
    ) -> Station:
        """Open the devices named in `urls` (family -> URL); robot and plc are required.
        `trace`: the wire trace of the devices whose URL asks for it (or of all: see
        drivers.trace); the station closes it after the devices. `defer_unreachable`: see the
        module docstring."""
        opened: dict[str, Device] = {}
        unreachable: dict[str, DeviceError] = {}
        options = options or {}
        register_fakes()  # a cell's fake:// devices are the simulated cell's
        try:
            for family in ORDER:
                if family not in urls:
                    continue
                kw = dict(options.get(family, {}))
                if family == "robot":
                    kw.setdefault("guard", guard or SafetyGuard())
                if family == "camera" and "galvo" in opened and urls[family] == "fake://":
                    kw.setdefault("galvo", opened["galvo"])  # the fake renders the galvo's angle
                device = create_device(family, urls[family], trace=trace, **kw)
                opened[family] = device  # built: closed (a no-op if unopened) on failure
                try:
                    device.open()
                except DeviceConfigError:
                    raise
                except DeviceError as exc:
                    _stamp(exc, device)
                    if not defer_unreachable:
                        raise
                    unreachable[family] = exc
            return cls(
                robot=cast(Robot, opened["robot"]),
                plc=cast(Plc, opened["plc"]),
                camera=cast(Camera | None, opened.get("camera")),
                galvo=cast(Galvo | None, opened.get("galvo")),
                tracker=cast(Tracker | None, opened.get("tracker")),
                urls={family: urls[family] for family in opened},
                trace=trace,
                unreachable=unreachable,
            )
        except BaseException:
            for device in reversed(opened.values()):
                device.close()
            if trace is not None:
                trace.close()
            raise

    def open_unreachable(self) -> dict[str, DeviceError]:
        """Try to open every device in `unreachable` again (in ORDER); the ones still
        unreachable, with their new errors (empty: every device is open)."""
        devices, still = self.devices(), {}
        for family in [f for f in ORDER if f in self.unreachable]:
            device = devices[family]
            try:
                device.open()
            except DeviceError as exc:
                still[family] = _stamp(exc, device)
        self.unreachable = still  # replaced whole: the status reply reads it from its thread
        return dict(still)

    def reopen_lost(self) -> dict[str, DeviceError]:
        """Close and open again every device that was lost while running (`Device.needs_reopen`:
        a camera that went away) or left closed by a reopen that failed, in ORDER (not those
        unreachable since the start: `open_unreachable`); the ones that do not open, with
        their errors (empty: every device is open)."""
        failed: dict[str, DeviceError] = {}
        for family, device in self.devices().items():
            if family in self.unreachable or (device.is_open and not device.needs_reopen):
                continue
            device.close()
            try:
                device.open()
            except DeviceError as exc:
                failed[family] = _stamp(exc, device)
        return failed

    def devices(self) -> dict[str, Device]:
        out: dict[str, Device | None] = {
            "plc": self.plc,
            "robot": self.robot,
            "galvo": self.galvo,
            "camera": self.camera,
            "tracker": self.tracker,
        }
        return {k: v for k, v in out.items() if v is not None}

    def close(self) -> None:
        """Close every device (never raises)."""
        for device in reversed(list(self.devices().values())):
            with contextlib.suppress(Exception):
                device.close()
        if self.trace is not None:
            self.trace.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _stamp(exc: DeviceError, device: Device) -> DeviceError:
    """The device's stamp on an error of its open() (drivers.base stamps its other methods)."""
    if exc.family is None:
        exc.family, exc.device = device.family, device.name
    return exc


def cell_guard(cfg: Any) -> SafetyGuard:
    """The safety guard of a resolved cell configuration: the cell's joint limits ([robot],
    whose defaults are calib.robot's nominal M-710iC/50) and its joint speeds ([line])."""
    from drivers.safety import JointLimits

    limits = JointLimits(
        lower_deg=tuple(float(v) for v in cfg.limits.lower_deg),
        upper_deg=tuple(float(v) for v in cfg.limits.upper_deg),
        speed_deg_s=tuple(float(v) for v in cfg.line.joint_speed_deg_s),
    )
    return SafetyGuard(limits=limits)
