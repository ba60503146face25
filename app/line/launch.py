"""Building and serving the service: what `rvis run` does, in pieces the simulated line reuses.

    station = Station.open(cfg.devices, guard=...)          # or Station(robot=..., plc=...)
    service = build_service(cfg, station, sensor, settings, plan_path, x0, clock=...)
    serve(service)                                           # socket, SIGTERM, loop

`serve` runs the control socket and the service loop in the calling (main) thread until SIGTERM
or SIGINT, then stops safely: the running window finishes (the robot comes home), the
background identification is shut down and the database closed.
"""

from __future__ import annotations

import logging
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from app.line.clock import Clock
from app.line.control import ControlServer
from app.line.events import JsonLineFormatter
from app.line.measure import SphereSensor
from app.line.schedule import Schedule
from app.line.service import Service
from app.line.settings import ServiceSettings
from app.line.station import Station

SOCKET_NAME = "rvis.sock"


def build_service(
    cfg: Any,
    station: Station,
    sensor: SphereSensor,
    settings: ServiceSettings,
    plan_path: str | Path,
    x_initial: ArrayLike | None = None,
    *,
    clock: Clock | None = None,
) -> Service:
    """The service of a resolved cell configuration (app.config.CellConfig): the plan's
    schedule, the cell's spheres, its model ([calibration] model: rigid or compliant, with the
    thermal term) (x_initial: the starting parameters when the state directory has none yet;
    default nominal)."""
    schedule = Schedule.from_plan(plan_path, settings.line)
    model = cfg.identification_model()
    x0 = model.nominal_x() if x_initial is None else np.asarray(x_initial, dtype=float)
    return Service(
        station, sensor, schedule, cfg.spheres_part_mm, model, x0, clock=clock, settings=settings
    )


def json_logs(stream: Any = None, level: int = logging.INFO) -> logging.Handler:
    """Structured logs: every `rvis.*` record as one JSON line on stdout."""
    handler = logging.StreamHandler(stream or sys.stdout)
    handler.setFormatter(JsonLineFormatter())
    root = logging.getLogger("rvis")
    root.addHandler(handler)
    root.setLevel(level)
    return handler


def serve(service: Service) -> None:
    """Run the control socket and the service until SIGTERM/SIGINT (main thread only)."""

    def on_signal(signum: int, frame: FrameType | None) -> None:
        logging.getLogger("rvis.line").info("signal %d: stopping after the current window", signum)
        service.stop()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        with ControlServer(service, service.settings.state_dir / SOCKET_NAME):
            service.run()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
