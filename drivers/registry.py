"""Device selection by URL: one table of backends per family, imported only when chosen.

    fake://                              in-process fake on a fakes.world.World (``world=``)
    aravis://<camera-id>                 camera through Aravis (GenICam; GigE Vision, USB3 Vision)
    scpi+serial:///dev/ttyACM0?baud=115200   galvo DAC speaking SCPI over a serial port
    rmi://host:16001                     FANUC Remote Motion Interface
    modbus://host:502?unit=1             FANUC register mailbox over Modbus TCP (TP program)
    tracker+tcp://host:7700              laser-tracker side-car (docs/tracker-sidecar.md)
    tracker+file://targets.csv           tracker export (CSV) imported as measurements
    plc+modbus://host:502?unit=1         line PLC clamp-window handshake over Modbus TCP

``import drivers`` imports none of pymodbus, serial or gi: a backend module is imported when its
scheme is opened. Options not in the URL (guard, world, timeouts) are passed as keywords.
Every scheme takes ``?trace=1``: the device's wire traffic goes to the ``trace=`` file the caller
passes (drivers.trace.WireTrace; with its ``every_device`` set, every device is traced).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast
from urllib.parse import parse_qsl, unquote, urlsplit

from drivers.errors import DeviceConfigError

if TYPE_CHECKING:
    from drivers.base import Device
    from drivers.camera import Camera
    from drivers.galvo import Galvo
    from drivers.plc import Plc
    from drivers.robot import Robot
    from drivers.trace import WireTrace
    from drivers.tracker import Tracker

BACKENDS: dict[str, dict[str, str]] = {
    "camera": {
        "fake": "fakes.devices:FakeCamera",
        "aravis": "drivers.aravis_camera:AravisCamera",
    },
    "galvo": {
        "fake": "fakes.devices:FakeGalvo",
        "scpi+serial": "drivers.scpi_galvo:ScpiGalvo",
    },
    "robot": {
        "fake": "fakes.devices:FakeRobot",
        "rmi": "drivers.rmi:RmiRobot",
        "modbus": "drivers.modbus_robot:ModbusRobot",
    },
    "tracker": {
        "fake": "fakes.devices:FakeTracker",
        "tracker+tcp": "drivers.tracker_tcp:TcpTracker",
        "tracker+file": "drivers.tracker_file:FileTracker",
    },
    "plc": {
        "fake": "fakes.devices:FakePlc",
        "plc+modbus": "drivers.plc_modbus:ModbusPlc",
    },
}
FAMILIES = tuple(BACKENDS)


@dataclass(frozen=True)
class DeviceUrl:
    """A parsed device URL. ``location`` is host for network schemes, the path for files."""

    raw: str
    scheme: str
    host: str = ""
    port: int | None = None
    path: str = ""
    query: dict[str, str] = field(default_factory=dict)

    @property
    def location(self) -> str:
        return self.path or self.host

    def option(self, name: str, default: str) -> str:
        return self.query.get(name, default)

    def number(self, name: str, default: float) -> float:
        try:
            return float(self.query.get(name, default))
        except ValueError as exc:
            raise DeviceConfigError(f"{self.raw}: option {name!r} must be a number") from exc

    def flag(self, name: str, default: bool = False) -> bool:
        """A yes/no option: 1, true, yes, on or 0, false, no, off (DeviceConfigError else)."""
        text = self.query.get(name)
        if text is None:
            return default
        value = {"1": True, "true": True, "yes": True, "on": True, "": True}.get(text.lower())
        if value is None and text.lower() not in ("0", "false", "no", "off"):
            raise DeviceConfigError(f"{self.raw}: option {name!r} must be 1 or 0, got {text!r}")
        return bool(value)

    def address(self, default_port: int) -> tuple[str, int]:
        if not self.host:
            raise DeviceConfigError(f"{self.raw}: no host")
        return self.host, self.port if self.port is not None else default_port


def parse_url(url: str) -> DeviceUrl:
    """Split a device URL; DeviceConfigError if it is not one."""
    if not isinstance(url, str) or "://" not in url:
        raise DeviceConfigError(f"not a device URL: {url!r} (expected scheme://...)")
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError as exc:
        raise DeviceConfigError(f"{url}: bad port") from exc
    scheme = parts.scheme.lower()
    host = unquote(parts.hostname or "") if scheme != "aravis" else unquote(parts.netloc)
    path = unquote(parts.path)
    if scheme.endswith("+file"):  # tracker+file://targets.csv is a relative path
        host, path = "", unquote(parts.netloc) + path
    query = dict(parse_qsl(parts.query, keep_blank_values=True))
    return DeviceUrl(url, scheme, host, port, path, query)


def backend_class(family: str, scheme: str) -> type[Device]:
    """Import and return the backend class for ``family`` and URL ``scheme``."""
    if family not in BACKENDS:
        raise DeviceConfigError(f"unknown device family {family!r}; one of {', '.join(FAMILIES)}")
    target = BACKENDS[family].get(scheme)
    if target is None:
        known = ", ".join(f"{s}://" for s in BACKENDS[family])
        raise DeviceConfigError(f"no {family} backend for {scheme}://; known: {known}")
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:  # e.g. PyGObject or Aravis not installed
        raise DeviceConfigError(f"{scheme}:// backend unavailable: {exc}") from exc
    return cast("type[Device]", getattr(module, class_name))


def create_device(
    family: str, url: str, *, trace: WireTrace | None = None, **options: Any
) -> Device:
    """Build (not open) the device for ``url``; traced to ``trace`` when the URL says
    ``?trace=1`` or the trace is for every device."""
    parsed = parse_url(url)
    traced = parsed.flag("trace")
    if traced and trace is None:
        raise DeviceConfigError(f"{url}: trace=1 needs a trace file (the state directory's)")
    device = backend_class(family, parsed.scheme).from_url(parsed, **options)
    if trace is not None and (traced or trace.every_device):
        device.trace = trace.channel(family, device.name)
    return device


def open_device(family: str, url: str, **options: Any) -> Device:
    """Build and open the device for ``url``; close it (or use ``with``) when done."""
    return create_device(family, url, **options).open()


def open_camera(url: str, **options: Any) -> Camera:
    return cast("Camera", open_device("camera", url, **options))


def open_galvo(url: str, **options: Any) -> Galvo:
    return cast("Galvo", open_device("galvo", url, **options))


def open_robot(url: str, **options: Any) -> Robot:
    return cast("Robot", open_device("robot", url, **options))


def open_tracker(url: str, **options: Any) -> Tracker:
    return cast("Tracker", open_device("tracker", url, **options))


def open_plc(url: str, **options: Any) -> Plc:
    return cast("Plc", open_device("plc", url, **options))
