"""Building and serving the service: what `rvis run` does, in pieces the simulated line reuses.

    station = Station.open(cfg.devices, guard=...)          # or Station(robot=..., plc=...)
    service = build_service(cfg, station, sensor, settings, plan_path, x0, clock=...)
    serve(service)                                           # socket, SIGTERM, loop

`hold_state` comes first, before any device is opened: the state directory private to the
service (app.line.statedir.prepare), its exclusive lock (a second service exits 2 naming the
holder's pid), with `[service] operators_group` what it holds given that group and its modes
(a directory commissioned before the group was set: app.line.statedir.follow_group), and a
quick check of the database (a damaged one exits 2, untouched).
`serve` runs the control socket (and the OPC UA server, app.line.opcua) and the service loop
in the calling (main) thread until SIGTERM or SIGINT, then stops safely: the running window
finishes (the robot comes home), the background identification is shut down and the database
closed. It returns the process's exit status: 1 after an internal error (the cell in FAULT,
the supervisor restarts the process). SIGPIPE is ignored while it serves: a client that goes
away never ends the service.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from app.line.body_cycle import BodySetup
from app.line.control import ControlServer
from app.line.events import JsonLineFormatter
from app.line.measure import SphereSensor
from app.line.schedule import Schedule
from app.line.service import Service
from app.line.settings import ServiceSettings
from app.line.statedir import ServiceLock, StateDir, follow_group, prepare
from app.line.station import Station
from app.line.store import Store
from drivers.clock import Clock

__all__ = ["build_service", "hold_state", "json_logs", "serve", "serving"]


@contextlib.contextmanager
def hold_state(state_dir: str | Path, group: str = "") -> Iterator[StateDir]:
    """The state directory prepared, locked for this process and its database checked (see
    the module docstring); the lock is released on exit (and by the kernel on any death)."""
    paths = StateDir(state_dir)
    prepare(paths, group)
    with ServiceLock(paths):
        changed, failed = follow_group(paths, group)
        if changed or failed:
            _group_followed(paths, group, changed, failed)
        if paths.db.exists():
            Store(paths.db).close()  # DatabaseDamaged (exit 2) before any device opens
        yield paths


def _group_followed(paths: StateDir, group: str, changed: int, failed: list[Path]) -> None:
    """The start's line about files given the operators' group (and those it could not)."""
    log = logging.getLogger("rvis.line")
    if changed:
        log.info("%d entries of %s given the group %s", changed, paths.root, group)
    if failed:
        log.warning(
            "%d entries of %s keep another group or mode (e.g. %s): not this user's to change;"
            " `rvis state check` says how to fix them",
            len(failed),
            paths.root,
            failed[0],
        )


def build_service(
    cfg: Any,
    station: Station,
    sensor: SphereSensor,
    settings: ServiceSettings,
    plan_path: str | Path,
    x_initial: ArrayLike | None = None,
    *,
    clock: Clock | None = None,
    bodies: BodySetup | None = None,
) -> Service:
    """The service of a resolved cell configuration (app.config.CellConfig): the plan's
    schedule, the cell's spheres, its model ([service] model: rigid or compliant, with the
    thermal term) (x_initial: the starting parameters when the state directory has none yet;
    default nominal); `bodies`: the part type's features it measures (None: none)."""
    schedule = Schedule.from_plan(plan_path, settings.line)
    model = cfg.service_model()
    x0 = model.nominal_x() if x_initial is None else np.asarray(x_initial, dtype=float)
    return Service(
        station,
        sensor,
        schedule,
        cfg.spheres_part_mm,
        model,
        x0,
        clock=clock,
        settings=settings,
        bodies=bodies,
    )


def json_logs(
    stream: Any = None, level: int = logging.INFO, logger: str = "rvis"
) -> logging.Handler:
    """Structured logs: every record of `logger` (default every `rvis.*` one) as one JSON line
    on stdout; returns the handler (`logging.getLogger(logger).removeHandler` ends it)."""
    handler = logging.StreamHandler(stream or sys.stdout)
    handler.setFormatter(JsonLineFormatter())
    root = logging.getLogger(logger)
    root.addHandler(handler)
    root.setLevel(level)
    return handler


@contextlib.contextmanager
def serving(service: Service) -> Iterator[ControlServer]:
    """The control socket of `service` (and its OPC UA server when `[opcua] enabled`), with
    SIGPIPE ignored and an unexpected error in any thread of the process handed to the
    service (FAULT, exit status 1)."""
    main = threading.current_thread() is threading.main_thread()  # signals: main thread only
    previous_pipe = signal.signal(signal.SIGPIPE, signal.SIG_IGN) if main else None
    previous_hook = threading.excepthook

    def on_thread_error(args: threading.ExceptHookArgs) -> None:
        previous_hook(args)
        if args.exc_value is not None and not isinstance(args.exc_value, SystemExit):
            service.crash(args.exc_value)

    threading.excepthook = on_thread_error
    socket_path = StateDir(service.settings.state_dir).socket
    try:
        with (
            ControlServer(service, socket_path, on_error=service.crash) as server,
            contextlib.ExitStack() as plant,
        ):
            if service.settings.opcua.enabled:
                from app.line.opcua.server import OpcUaServer

                plant.enter_context(OpcUaServer(service))
            yield server
    finally:
        threading.excepthook = previous_hook
        if previous_pipe is not None:
            signal.signal(signal.SIGPIPE, previous_pipe)


def serve(service: Service) -> int:
    """Run the control socket and the service until SIGTERM/SIGINT (main thread only); the
    exit status (1 after an internal error)."""

    def on_signal(signum: int, frame: FrameType | None) -> None:
        logging.getLogger("rvis.line").info("signal %d: stopping after the current window", signum)
        service.stop()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        with serving(service):
            service.run()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return service.exit_code
