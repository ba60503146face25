"""One device looked at without changing it: what it says it is and a read-only probe (the
robot's joints, a frame, the galvo's command, the tracker's targets, the PLC's inputs; the PLC
is opened read-only by its callers). `rvis devices check` and `rvis commission` use it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.base import Device
from drivers.errors import DeviceTimeout


def describe_and_probe(device: Device) -> str:
    """``<describe()>; <probe>`` of an open device; a typed DeviceError when it fails."""
    return f"{device.describe()}; {PROBES[device.family](device)}"


def _probe_robot(robot: Any) -> str:
    q = ", ".join(f"{v:.2f}" for v in robot.joints_deg())
    return f"J1..J6 = {q} deg; servo ready {robot.status().servo_ready}"


def _probe_camera(camera: Any) -> str:
    """A frame (the driver re-triggers once); a second grab when that one was lost too (a
    GigE link that drops a frame now and then answers, one that drops four in a row does
    not)."""
    lost = ""
    try:
        frame = camera.grab()
    except DeviceTimeout as exc:
        lost = f" (after {exc})"
        frame = camera.grab()
    h, w = frame.image.shape
    return f"frame {frame.frame_id} {w}x{h} {frame.image.dtype}{lost}"


def _probe_galvo(galvo: Any) -> str:
    return f"command {galvo.volts() + 0.0:.3f} V"


def _probe_tracker(tracker: Any) -> str:
    status = tracker.status()
    return f"{len(tracker.targets())} targets; target in beam {status.target_in_beam}"


def _probe_plc(plc: Any) -> str:
    inputs = plc.poll()
    return f"window {inputs.window_open}, line {inputs.line_running}, beat {inputs.heartbeat}"


PROBES: dict[str, Callable[[Any], str]] = {
    "robot": _probe_robot,
    "camera": _probe_camera,
    "galvo": _probe_galvo,
    "tracker": _probe_tracker,
    "plc": _probe_plc,
}
