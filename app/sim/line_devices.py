"""The simulated line's devices as their own process (`rvis devices sim`): the unchanged
service (`rvis run --cell`) talks to them as it talks to a plant's.

    devices = LineDevices(cfg, Path("sim"), seed=7)     # cfg: the cell to simulate
    with devices:                                        # every peer up on 127.0.0.1
        devices.command("stop plc")                     # what `rvis devices ctl` sends
        ...

`start()` brings up every peer of fakes.line.SimLine (RMI robot controller, SCPI galvo DAC on
a pty behind a stable link, Aravis GigE fake camera, tracker side-car, Modbus PLC with the
clamp cycle), each on a free port, and writes the devices folder:

    DIR/cell.toml     the cell file naming them ([devices]), the PLC's clamp window in wall
                      seconds ([line] window_s), the words the simulated PLC writes ([line]
                      plc_temperature, plc_body_id) and the seed ([simulation] seed)
    DIR/plan.json     the plan for that cell (the spheres where the cell puts them: fixed
                      placement, as `rvis plan --placement fixed`)
    DIR/sensor.toml   the simulated sensor's own calibration (a perfect `rvis sensor calibrate`)
    DIR/galvo         the galvo DAC's stable name (its pty changes when it comes back)
    DIR/devices.sock  the control socket (`rvis devices ctl`)

The cell, plan and sensor files have the state directory's names (app/line/statedir.py), so a
service started with `--state-dir DIR` finds all three there. A folder whose cell file was not
written here (a commissioned state directory) is refused: its cell file is the cell's record.

Time: the devices run on the wall clock (a fakes.clock.ScaledClock, `scale` sim seconds per
real second, 1 by default), as a plant's devices do; the service in its own process runs on its
real clock. The clamp cycle, the warm-up and a knock follow the devices' clock; with scale > 1
the cell's [line] window_s is the window in wall seconds (the PLC sends only the bit). The
virtual clock of `rvis run --sim` cannot serve here: it moves only when the service's own waits
make it pass, and this service waits on the wall clock in another process.

Control: one text line per request (`stop plc`, `start plc`, `break camera`, `fix camera`,
`status`, `quit`), one JSON line per reply: `{"ok": true, "message": ..., "devices": {family:
{"url", "state"}}}` or `{"ok": false, "error": ...}`. `stop` switches a device off (its port
closes: connection refused; the galvo's pty vanishes; the camera answers no more), `start`
switches it on again at the same URL; `break` makes a device misbehave while it answers (the
PLC's heartbeat freezes, the camera stops streaming: until `fix`; the robot's next motion
stops on a controller alarm, the galvo's next command queues an error: once).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import socket
import socketserver
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

from app.config import CellConfig
from app.config.write import dumps_cell
from app.errors import InputError, RvisError
from app.line.statedir import StateDir
from fakes.line import DEVICES, SimLine
from fakes.line_faults import Fault

CONTROL_NAME = "devices.sock"
GALVO_LINK_NAME = "galvo"
#: the first line of the cell files written here (and how a rewrite knows its own file)
MARK = "written by `rvis devices sim`"

#: what `break DEVICE` plays (fakes.line_faults); the lasting ones end with `fix` or `start`
BREAKS = {
    "plc": Fault.PLC_HEARTBEAT_LOSS,
    "camera": Fault.CAMERA_TIMEOUT,
    "robot": Fault.CONTROLLER_ALARM,
    "galvo": Fault.GALVO_ERROR,
}
LASTING = {"plc", "camera"}
BREAK_TEXT = {
    "plc": "the PLC's heartbeat freezes (until `fix plc`)",
    "camera": "the camera stops streaming (until `fix camera`)",
    "robot": "the robot's next motion stops half-way on a controller alarm",
    "galvo": "the galvo's next voltage command queues a hardware error (-240)",
}
COMMANDS = ("status", "stop", "start", "break", "fix", "quit")


@dataclasses.dataclass(frozen=True)
class DevicesDir:
    """The paths of a devices folder (module docstring)."""

    root: Path

    @property
    def cell(self) -> Path:
        return StateDir(self.root).cell

    @property
    def plan(self) -> Path:
        return StateDir(self.root).plan

    @property
    def sensor(self) -> Path:
        return StateDir(self.root).sensor

    @property
    def control(self) -> Path:
        return self.root / CONTROL_NAME

    @property
    def galvo(self) -> Path:
        return self.root / GALVO_LINK_NAME


def devices_cell(cfg: CellConfig, urls: dict[str, str], seed: int, scale: float) -> CellConfig:
    """The cell file of the simulated line's devices: `cfg` with the devices' URLs, the clamp
    window in wall seconds at `scale` sim seconds per real second, the words the simulated PLC
    writes (app.sim.line_setup.with_simulated_plc) and the seed."""
    from app.sim.line_setup import with_simulated_plc

    cfg = with_simulated_plc(cfg)
    devices = dataclasses.replace(
        cfg.devices,
        robot=urls["robot"],
        camera=urls["camera"],
        galvo=urls["galvo"],
        tracker=urls["tracker"],
        plc=urls["plc"],
    )
    line = dataclasses.replace(cfg.line, window_s=cfg.simline.window_s / scale)
    simulation = dataclasses.replace(cfg.simulation, seed=seed)
    return dataclasses.replace(cfg, devices=devices, line=line, simulation=simulation)


def check_folder(folder: DevicesDir) -> None:
    """Refuse a folder whose cell file is not one this module wrote (a commissioned state
    directory: its cell file is the record of the cell), a folder with a plan or sensor file
    but none of its cell files, a path that is not a folder, or a file where the galvo's link
    goes (a link left by a killed devices process is fine: it is replaced, never followed)."""
    if folder.root.exists() and not folder.root.is_dir():
        raise InputError("not a folder", file=folder.root)
    if os.path.lexists(folder.galvo) and not folder.galvo.is_symlink():
        raise InputError(
            "not the galvo's link of `rvis devices sim` (a file in its place): move it away",
            file=folder.galvo,
        )
    try:
        first = folder.cell.read_text(encoding="utf-8").splitlines()[:1]
    except FileNotFoundError:
        for other in (folder.plan, folder.sensor):
            if other.exists():  # written by someone else: `rvis commission`, a person
                raise InputError(
                    "a folder with a plan or sensor file and no cell file of `rvis devices"
                    " sim`: give the devices another --dir",
                    file=other,
                ) from None
        return
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read: {exc}", file=folder.cell) from exc
    if not (first and first[0].startswith(f"# {MARK}")):
        raise InputError(
            "a cell file not written by `rvis devices sim` (a commissioned state directory?):"
            " give the devices another --dir, and this file as --cell",
            file=folder.cell,
        )


class LineDevices:
    """The simulated line's devices with their control socket (module docstring)."""

    def __init__(
        self,
        cfg: CellConfig,
        root: Path,
        *,
        seed: int,
        scale: float = 1.0,
        camera_address: str = "127.0.0.1",
        progress: Callable[[str], None] = lambda text: None,
    ) -> None:
        if not scale > 0:
            raise InputError(f"must be > 0, got {scale}", field="--scale")
        self.cfg, self.seed, self.scale = cfg, seed, float(scale)
        self.folder = DevicesDir(Path(root))
        self.camera_address = camera_address
        self.progress = progress
        self.broken: set[str] = set()  # devices with a lasting break
        self.line: SimLine | None = None
        self.started_unix_s = 0.0
        self.quit = threading.Event()  # set by the `quit` command
        self._lock = threading.Lock()  # one command at a time
        self._server: _ControlServer | None = None
        self._thread: threading.Thread | None = None
        self._stack = contextlib.ExitStack()

    # -- life cycle -----------------------------------------------------------------------------
    def __enter__(self) -> Self:
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        check_folder(self.folder)
        self.folder.root.mkdir(parents=True, exist_ok=True)
        self._stop_stale_socket()
        line = self._start_line()
        # the wall clock's Unix time of the line's sim time 0 (its clock runs x scale from it)
        self.started_unix_s = time.time() - line.clock.monotonic() / self.scale
        cfg = devices_cell(self.cfg, line.urls, self.seed, self.scale)
        self._write_files(cfg, line)
        self._serve()

    def _start_line(self) -> SimLine:
        from app.sim.cell import make_cell
        from app.sim.line_setup import simline_settings

        setup = dataclasses.replace(
            simline_settings(self.cfg, geometric=False),
            clock="scaled",
            scale=self.scale,
            camera_address=self.camera_address,
            # absolute (the service runs elsewhere), the folder resolved but not the link: a
            # link left by a killed devices process names a pty that is not ours any more
            galvo_link=str(self.folder.root.resolve() / GALVO_LINK_NAME),
            # a person's command waits for another simulation's camera as long as it runs, and
            # says at once for which process
            camera_wait_s=None,
            camera_on_wait=self.progress,
        )
        self.progress(
            f"starting the devices of the simulated cell (seed {self.seed}; the GigE fake camera"
            f" on {self.camera_address}, after any other simulation's camera there has closed)"
        )
        cell = make_cell(self.cfg, seed=self.seed)
        self.line = SimLine(cell, setup)
        try:
            self._stack.enter_context(self.line)
        except (RuntimeError, ImportError, OSError) as exc:
            hint = ""
            if "could not bind" in str(exc):
                hint = " (--camera-address: an address of one of this machine's interfaces)"
            raise RvisError(f"the simulated line's devices could not start: {exc}{hint}") from exc
        return self.line

    def _write_files(self, cfg: CellConfig, line: SimLine) -> None:
        from app.formats.files import write_json, write_text
        from app.meta import provenance
        from app.planning import plan_to_json, run_plan
        from app.sim.cell import true_sensor_model
        from vision.sensor_model import dumps_sensor_model

        header = (
            f"{MARK} (seed {self.seed}, {self.scale:g} sim s per real s, pid {os.getpid()}):\n"
            f"the simulated line's devices; control: rvis devices ctl --dir {self.folder.root}"
        )
        write_text(self.folder.sensor, dumps_sensor_model(true_sensor_model(line.cell.sensor)))
        self.progress(f"planning for {self.folder.root}'s cell (fixed placement)")
        model = cfg.identification_model()
        x = model.nominal_x()
        result = run_plan(cfg, model, x, placement="fixed")
        doc = {
            **plan_to_json(cfg, model, x, result),
            "provenance": provenance(result.settings.seed),
        }
        write_json(self.folder.plan, doc)
        # the cell file last: once it is there, so is all the service needs (a script that
        # waits for it starts `rvis run --cell` then, as a person does at the printed line)
        write_text(self.folder.cell, dumps_cell(cfg, header))

    def _stop_stale_socket(self) -> None:
        """A socket file left by a killed devices process is removed; one that answers is
        another devices process on this folder: refused."""
        path = self.folder.control
        if not path.exists():
            return
        with socket.socket(socket.AF_UNIX) as probe:
            try:
                probe.connect(str(path))
            except OSError:
                path.unlink(missing_ok=True)
                return
        raise InputError("the simulated line's devices already run on this folder", file=path)

    def _serve(self) -> None:
        server = _ControlServer(str(self.folder.control), _ControlHandler)
        server.devices = self
        self._server = server
        self._thread = threading.Thread(
            target=server.serve_forever, name="devices-ctl", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        """Stop the control socket and every device (idempotent)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
            with contextlib.suppress(FileNotFoundError):
                self.folder.control.unlink()
        self._stack.close()

    # -- commands ---------------------------------------------------------------------------------
    def command(self, text: str) -> dict[str, Any]:
        """Execute one control line; the reply (module docstring)."""
        words = text.split()
        if not words or words[0] not in COMMANDS:
            return _error(f"unknown command {text.strip()!r}: one of {', '.join(COMMANDS)}")
        verb, rest = words[0], words[1:]
        if verb in ("status", "quit"):
            if rest:
                return _error(f"{verb} takes no device")
            if verb == "quit":
                self.quit.set()
                return {"ok": True, "message": "stopping the devices", **self.status()}
            return {"ok": True, "message": "", **self.status()}
        line = self.line
        assert line is not None
        if len(rest) != 1 or rest[0] not in line.families():
            return _error(f"{verb} needs one device: one of {', '.join(line.families())}")
        with self._lock:
            message = getattr(self, f"_{verb}")(line, rest[0])
        return {"ok": True, "message": message, **self.status()}

    def _stop(self, line: SimLine, family: str) -> str:
        line.stop_device(family)
        self.broken.discard(family)
        return f"{family} stopped (off: {line.urls[family]} answers no more)"

    def _start(self, line: SimLine, family: str) -> str:
        line.start_device(family)
        self.broken.discard(family)
        return f"{family} started ({line.urls[family]})"

    def _break(self, line: SimLine, family: str) -> str:
        if family not in BREAKS:
            raise _Refused(f"{family} has no break (stop it instead)")
        if family in line.stopped:
            raise _Refused(f"{family} is stopped (start it first)")
        line.inject(BREAKS[family])
        if family in LASTING:
            self.broken.add(family)
        return f"{family} broken: {BREAK_TEXT[family]}"

    def _fix(self, line: SimLine, family: str) -> str:
        if family not in self.broken:
            return f"{family} is not broken"
        line.clear(BREAKS[family])
        self.broken.discard(family)
        return f"{family} fixed"

    def status(self) -> dict[str, Any]:
        """Each device's URL and state (up, stopped, broken), the folder's files, the seed, the
        devices' clock (sim time now; the Unix time its sim time 0 was: the clamp window k opens
        (k + 1) period_s - window_s sim seconds after it)."""
        line = self.line
        assert line is not None
        devices = {}
        for family in DEVICES:
            if family in line.families():
                state = "stopped" if family in line.stopped else "up"
                devices[family] = {
                    "url": line.urls[family],
                    "state": "broken" if family in self.broken else state,
                }
        return {
            "devices": devices,
            "cell": str(self.folder.cell),
            "plan": str(self.folder.plan),
            "sensor": str(self.folder.sensor),
            "control": str(self.folder.control),
            "seed": self.seed,
            "scale": self.scale,
            "sim_time_s": round(line.clock.monotonic(), 3),
            "started_unix_s": self.started_unix_s,
            "pid": os.getpid(),
        }


class _Refused(Exception):
    """A command that cannot be done in the devices' present state (its reply's error)."""


def _error(text: str) -> dict[str, Any]:
    return {"ok": False, "error": text}


class _ControlServer(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    daemon_threads = True
    devices: LineDevices


class _ControlHandler(socketserver.StreamRequestHandler):
    """One client: a reply line for every request line, until it closes."""

    server: _ControlServer

    def handle(self) -> None:
        for raw in self.rfile:
            try:
                reply = self.server.devices.command(raw.decode("utf-8", errors="replace"))
            except (_Refused, ValueError) as exc:
                reply = _error(str(exc))
            try:
                self.wfile.write((json.dumps(reply) + "\n").encode())
                self.wfile.flush()
            except OSError:
                return  # the client went: its loss only


def send(folder: Path, text: str, timeout_s: float = 30.0) -> dict[str, Any]:
    """Send one control line to the devices of `folder`; their reply. InputError when no
    devices process answers there."""
    path = DevicesDir(folder).control
    with socket.socket(socket.AF_UNIX) as sock:
        sock.settimeout(timeout_s)
        try:
            sock.connect(str(path))
        except OSError as exc:
            raise InputError(
                f"no simulated line's devices answer here ({exc.strerror or exc}): start them"
                f" with `rvis devices sim --dir {folder}`",
                file=path,
            ) from exc
        sock.sendall(text.strip().encode() + b"\n")
        reply = b""
        deadline = time.monotonic() + timeout_s
        while not reply.endswith(b"\n") and time.monotonic() < deadline:
            chunk = sock.recv(65536)
            if not chunk:
                break
            reply += chunk
    doc: dict[str, Any] = json.loads(reply) if reply.strip() else _error("no reply")
    return doc
