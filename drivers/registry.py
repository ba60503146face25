"""Device selection by URL: one table of backends per family, imported only when chosen.

    fake://                              in-process fake on a fakes.world.World (``world=``),
                                         once registered (fakes.wiring.register_fakes)
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
from typing import TYPE_CHECKING, Any, cast

from drivers.errors import DeviceConfigError
from drivers.url import parse_url

if TYPE_CHECKING:
    from drivers.base import Device
    from drivers.camera import Camera
    from drivers.galvo import Galvo
    from drivers.plc import Plc
    from drivers.robot import Robot
    from drivers.trace import WireTrace
    from drivers.tracker import Tracker

BACKENDS: dict[str, dict[str, str]] = {
    "camera": {"aravis": "drivers.aravis_camera:AravisCamera"},
    "galvo": {"scpi+serial": "drivers.scpi_galvo:ScpiGalvo"},
    "robot": {"rmi": "drivers.rmi:RmiRobot", "modbus": "drivers.modbus_robot:ModbusRobot"},
    "tracker": {
        "tracker+tcp": "drivers.tracker_tcp:TcpTracker",
        "tracker+file": "drivers.tracker_file:FileTracker",
    },
    "plc": {"plc+modbus": "drivers.plc_modbus:ModbusPlc"},
}
FAMILIES = tuple(BACKENDS)


def register_backend(family: str, scheme: str, target: str) -> None:
    """Add (or replace) the backend `module:Class` of `family` for URLs of `scheme`, imported
    when first opened. The drivers know their own schemes; `fake://` is registered by whoever
    wires the simulated cell in (fakes.wiring.register_fakes), so that drivers/ names nothing
    of fakes/."""
    if family not in BACKENDS:
        raise DeviceConfigError(f"unknown device family {family!r}; one of {', '.join(FAMILIES)}")
    BACKENDS[family][scheme] = target


def backend_class(family: str, scheme: str) -> type[Device]:
    """Import and return the backend class for ``family`` and URL ``scheme``."""
    if family not in BACKENDS:
        raise DeviceConfigError(f"unknown device family {family!r}; one of {', '.join(FAMILIES)}")
    target = BACKENDS[family].get(scheme)
    if target is None:
        known = ", ".join(f"{s}://" for s in BACKENDS[family])
        hint = " (the simulated cell's: not wired in here)" if scheme == "fake" else ""
        raise DeviceConfigError(f"no {family} backend for {scheme}://{hint}; known: {known}")
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
