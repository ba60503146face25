"""`rvis devices check [--cell cell.toml] [--json]`: connect to each configured device, probe it
and print a status table. `rvis devices trace FILE [--rotated] [--device FAMILY] [--all] [--json]`:
print a wire trace (drivers/trace.py; the state directory's `trace/wire.jsonl`) readably, the
polls that changed nothing folded (app/formats/wiretrace.py) unless --all.

`rvis devices sim [--dir DIR] [--cell cell.toml] [--seed N] [--scale X] [--camera-address A]`:
the simulated line's devices (robot controller, galvo, camera, tracker, PLC) as their own
process on free ports of 127.0.0.1, until Ctrl-C, SIGTERM or `quit` (exit 0, as `rvis run`);
it writes DIR/cell.toml naming them, DIR/plan.json and DIR/sensor.toml (app/sim/line_devices.py),
so that the unchanged service runs on them as at a plant: `rvis run --cell DIR/cell.toml
--state-dir DIR`. `rvis devices ctl [--dir DIR] stop|start|break|fix DEVICE | status | quit`:
switch a device off and on, make it misbehave, while both run (docs/simulated-line.md).

Without ``--cell`` it checks every backend against the fakes out of the box: the protocol peers
(RMI controller, Modbus TP mailbox, tracker side-car, line PLC, SCPI DAC on a pty, Aravis GigE
fake camera) are started on 127.0.0.1 with ephemeral ports, plus the in-process ``fake://``
backends. With ``--cell`` it reads the ``[devices]`` table (keys camera, galvo, robot, tracker,
plc; values device URLs). The PLC is opened read-only: the check never writes the app's words
of a live line. Exit 0 when every device answered, 1 when one failed, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.args import int_at_least
from app.devicecheck import describe_and_probe
from app.errors import InputError
from drivers import DeviceConfigError, DeviceError, create_device
from drivers.registry import FAMILIES
from fakes.wiring import register_fakes
from fakes.world import StaticWorld


@dataclass
class Row:
    family: str
    url: str
    status: str  # OK, FAIL, SKIP
    detail: str


def register(sub: Any) -> None:
    parser = add_command(sub, "devices")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print JSON (check: the table; trace: one per line; sim: the devices once up;"
        " ctl: the reply)",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    check = actions.add_parser("check", help="connect to each device and print a status table")
    check.add_argument("--cell", type=Path, help="cell configuration (TOML) with a [devices] table")
    check.add_argument("--timeout", type=float, default=3.0, help="per-device timeout [s]")
    check.add_argument(
        "--trace", type=Path, metavar="FILE", help="trace every device's wire traffic to FILE"
    )
    check.set_defaults(func=run_check)
    trace = actions.add_parser("trace", help="print a wire trace readably")
    trace.add_argument("file", type=Path, help="trace file (STATE_DIR/trace/wire.jsonl)")
    trace.add_argument(
        "--rotated", action="store_true", help="also the rotated older files (FILE.1, ...)"
    )
    trace.add_argument(
        "--device", action="append", choices=FAMILIES, help="only this device (repeatable)"
    )
    trace.add_argument(
        "--all",
        action="store_true",
        help="print every record (default: polls that changed nothing folded into one line)",
    )
    trace.set_defaults(func=run_trace)
    sim = actions.add_parser(
        "sim", help="the simulated line's devices as their own process, with a cell file"
    )
    sim.add_argument(
        "--dir",
        type=Path,
        default=Path(SIM_DIR),
        help=f"folder of the cell file, plan, sensor file, control socket (default {SIM_DIR})",
    )
    sim.add_argument("--cell", type=Path, help="the cell to simulate (default: the embedded cell)")
    sim.add_argument("--seed", type=int_at_least(0), help="seed (default [simulation] seed)")
    sim.add_argument(
        "--scale", type=float, default=1.0, help="sim seconds per real second (default 1)"
    )
    sim.add_argument(
        "--camera-address",
        default="127.0.0.1",
        help="the GigE fake camera's address, one of this machine's (default 127.0.0.1)",
    )
    sim.set_defaults(func=run_sim)
    ctl = actions.add_parser("ctl", help="stop, start or break a simulated device while it runs")
    ctl.add_argument(
        "--dir", type=Path, default=Path(SIM_DIR), help=f"the devices' folder (default {SIM_DIR})"
    )
    ctl.add_argument("words", nargs="+", metavar="COMMAND", help=CTL_HELP)
    ctl.set_defaults(func=run_ctl)


#: the folder of `rvis devices sim` when --dir is not given
SIM_DIR = "rvis-simline"
CTL_HELP = "stop DEVICE | start DEVICE | break DEVICE | fix DEVICE | status | quit"


def run_check(args: argparse.Namespace) -> int:
    if args.timeout <= 0:
        raise InputError("must be > 0", field="--timeout")
    world = StaticWorld()
    with ExitStack() as stack:
        trace = None
        if args.trace is not None:
            from drivers.trace import WireTrace

            trace = stack.enter_context(WireTrace(args.trace, every_device=True))
        if args.cell is None:
            devices = _start_peers(world, stack)
        else:
            devices = [(f, u, None) for f, u in read_cell_devices(args.cell).items()]
        rows = [_check(f, u, skip, world, args.timeout, args.cell, trace) for f, u, skip in devices]
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=2))
    else:
        _print_table(rows)
    return 0 if all(r.status != "FAIL" for r in rows) else 1


def read_cell_devices(path: Path) -> dict[str, str]:
    """The device URLs of a cell file (every family; the fake where the file names none)."""
    from app.config import load_cell

    return load_cell(path).devices.urls()


def _start_peers(world: StaticWorld, stack: ExitStack) -> list[tuple[str, str, str | None]]:
    from fakes.modbus_robot import ModbusRobotServer
    from fakes.plc import PlcServer
    from fakes.rmi_controller import RmiController
    from fakes.scpi_dac import ScpiDac
    from fakes.tracker_service import TrackerService

    rmi = stack.enter_context(RmiController(world))
    mbx = stack.enter_context(ModbusRobotServer(world))
    trk = stack.enter_context(TrackerService(world))
    plc = stack.enter_context(PlcServer())
    dac = stack.enter_context(ScpiDac())
    out: list[tuple[str, str, str | None]] = [(f, "fake://", None) for f in FAMILIES]
    out += [
        ("robot", f"rmi://127.0.0.1:{rmi.port}", None),
        ("robot", f"modbus://127.0.0.1:{mbx.port}", None),
        ("tracker", f"tracker+tcp://127.0.0.1:{trk.port}", None),
        ("plc", f"plc+modbus://127.0.0.1:{plc.port}", None),
        ("galvo", f"scpi+serial://{dac.port}", None),
    ]
    try:
        from fakes.gv_camera import GvCamera

        gv = stack.enter_context(GvCamera(world))
        out.append(("camera", f"aravis://{gv.camera_id}", None))
    except (ImportError, ValueError, RuntimeError) as exc:
        out.append(("camera", "aravis://127.0.0.1", f"Aravis unavailable: {exc}"))
    return out


def _check(
    family: str,
    url: str,
    skip: str | None,
    world: StaticWorld,
    timeout: float,
    cell: Path | None,
    trace: Any = None,
) -> Row:
    if skip:
        return Row(family, url, "SKIP", skip)
    options: dict[str, Any] = {"timeout_s": timeout, "trace": trace}
    if url.startswith("fake://"):
        options["world"] = world
    if family == "plc":
        options["read_only"] = True  # looking at a live line never changes its handshake
    register_fakes()  # a cell's fake:// devices are the simulated cell's
    try:
        device = create_device(family, url, **options)
    except DeviceConfigError as exc:
        if cell is None:
            return Row(family, url, "FAIL", str(exc))
        raise InputError(str(exc), file=cell, field=f"devices.{family}") from exc
    try:
        with device:
            return Row(family, url, "OK", describe_and_probe(device))
    except DeviceError as exc:
        return Row(family, url, "FAIL", f"{type(exc).__name__}: {exc}")


def _print_table(rows: list[Row]) -> None:
    widths = [max(len(getattr(r, k)) for r in rows) for k in ("family", "url", "status")]
    for r in rows:
        print(f"{r.family:<{widths[0]}}  {r.url:<{widths[1]}}  {r.status:<{widths[2]}}  {r.detail}")


def run_trace(args: argparse.Namespace) -> int:
    from app.formats.wiretrace import format_records, read_records, rotated, to_json

    if not args.file.is_file():
        raise InputError("trace file not found", file=args.file)
    files = rotated(args.file) if args.rotated else [args.file]
    wanted = set(args.device or ())
    records = (r for f in files for r in read_records(f) if not wanted or r.device in wanted)
    lines = (to_json(r) for r in records) if args.json else format_records(records, not args.all)
    for line in lines:
        print(line)
    return 0


def run_sim(args: argparse.Namespace) -> int:
    """Until Ctrl-C, SIGTERM or `quit`: exit 0 (as `rvis run`); a Ctrl-C or SIGTERM while the
    devices start (waiting for another simulation's camera, say) is an interruption (130), the
    devices started so far closed and the galvo's link removed."""
    import sys
    import threading

    from app.config import load_cell
    from app.sim.line_devices import LineDevices

    if args.cell is not None and not args.cell.is_file():
        raise InputError("file not found", file=args.cell)
    cfg = load_cell(args.cell)
    seed = cfg.simulation.seed if args.seed is None else args.seed

    def say(text: str) -> None:
        print(f"rvis devices sim: {text}", file=sys.stderr, flush=True)

    stop, up = threading.Event(), threading.Event()
    with (
        _stopped_by_signals(stop, interrupt=lambda: not up.is_set()),
        LineDevices(
            cfg,
            args.dir,
            seed=seed,
            scale=args.scale,
            camera_address=args.camera_address,
            progress=say,
        ) as devices,
    ):
        up.set()
        status = devices.status()
        if args.json:
            print(json.dumps(status), flush=True)
        else:
            _print_devices(status, _state_dir_of(args.cell) or args.dir)
        while not (stop.is_set() or devices.quit.is_set()):
            stop.wait(0.5)  # the main thread stays where a signal handler can run
        say("stopping the devices")
    return 0


@contextmanager
def _stopped_by_signals(stop: Any, interrupt: Callable[[], bool]) -> Iterator[None]:
    """SIGTERM and SIGINT set `stop` meanwhile, and while `interrupt()` says so (the devices
    still starting) raise KeyboardInterrupt where the main thread is, so that what started is
    closed; the handlers before are put back after."""
    import signal

    def on_signal(signum: int, frame: object) -> None:
        stop.set()
        if interrupt():
            raise KeyboardInterrupt

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _state_dir_of(cell: Path | None) -> Path | None:
    """The state directory whose commissioned cell file `cell` is (its plan beside it), if
    any: the service runs on it."""
    from app.line.statedir import StateDir

    if cell is None:
        return None
    state = StateDir(cell.parent)
    same = state.cell.resolve() == cell.resolve()
    return cell.parent if same and state.plan.is_file() else None


def _print_devices(status: dict[str, Any], state_dir: Path) -> None:
    folder = Path(status["cell"]).parent
    for family, d in status["devices"].items():
        print(f"{family:<8} {d['url']}")
    print(f"cell     {status['cell']} (seed {status['seed']}, plan and sensor beside it)")
    print(f"control  rvis devices ctl --dir {folder} stop|start|break|fix DEVICE | status | quit")
    print(f"service  rvis run --cell {status['cell']} --state-dir {state_dir}", flush=True)


def run_ctl(args: argparse.Namespace) -> int:
    from app.sim.line_devices import send

    reply = send(args.dir, " ".join(args.words))
    if args.json:
        print(json.dumps(reply))
    elif not reply.get("ok"):
        import sys

        print(f"rvis devices: error: {reply.get('error')}", file=sys.stderr)
    else:
        if reply.get("message"):
            print(reply["message"])
        if args.words[0] == "status":
            for family, d in reply["devices"].items():
                print(f"{family:<8} {d['state']:<8} {d['url']}")
    return 0 if reply.get("ok") else 1
