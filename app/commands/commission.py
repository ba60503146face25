"""`rvis commission [--cell cell.toml] [--state-dir DIR] [--yes] [--restart] [--sensor FILE |
--sensor-data DIR] [--targets FILE] [--json]`, `rvis commission --sim [--geometric] [--seed N]`:
the guided, resumable commissioning of a cell (app/commission/, docs/commissioning.md).

Each step and every robot motion waits for the engineer's yes (`--yes` gives it for a scripted
run); the results go to STATE_DIR/commission/ with the report (commission.md, commission.json);
run again, it continues at the first step not passed. Exit 0 when every step passed (the state
directory is ready for `rvis run`), 3 when a step failed its checks (fix the cause and run
again), 1 when the engineer stopped it, 2 on bad input.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.args import int_at_least, say_waiting
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "commission")
    p.add_argument("--cell", type=Path, help="cell configuration TOML (default: embedded)")
    p.add_argument("--state-dir", type=Path, help="state directory (default: [service])")
    p.add_argument("--yes", action="store_true", help="confirm every step and motion")
    p.add_argument("--restart", action="store_true", help="begin again (old results kept)")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--sensor", type=Path, help="a sensor calibration made elsewhere")
    source.add_argument("--sensor-data", type=Path, help="sensor targets recorded earlier")
    p.add_argument("--targets", type=Path, help="the tracker's export of the sphere centres")
    p.add_argument("--sim", action="store_true", help="on the simulated line (no hardware)")
    p.add_argument("--geometric", action="store_true", help="--sim: measure without rendering")
    p.add_argument("--seed", type=int_at_least(0), help="--sim: seed (default [simulation])")
    p.add_argument("--json", action="store_true", help="print the report as JSON at the end")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.config import load_cell
    from app.line.launch import hold_state

    if not args.sim and (args.geometric or args.seed is not None):
        raise InputError("--geometric and --seed need --sim")
    for path in (args.sensor, args.targets):
        if path is not None and not path.is_file():
            raise InputError("file not found", file=path)
    if args.sensor_data is not None and not args.sensor_data.is_dir():
        raise InputError("folder not found", file=args.sensor_data)
    cfg = load_cell(args.cell)
    state_dir = args.state_dir or Path(cfg.service.state_dir)
    say = _printer(sys.stderr if args.json else sys.stdout)
    confirm = _confirmation(args.yes, say)
    seed = cfg.simulation.seed if args.seed is None else args.seed
    setup = {"cell": cfg.source, "simulated": args.sim}
    if args.sim:
        setup |= {"seed": seed, "geometric": args.geometric}
    with hold_state(state_dir, str(cfg.service.operators_group)) as state, ExitStack() as stack:
        if args.restart and state.commission.exists():
            kept = state.commission_kept(f"{datetime.now(UTC):%Y%m%dT%H%M%S}")
            state.commission.rename(kept)
            say(f"the earlier commissioning is kept in {kept}")
        from app.commission.journal import Journal

        if args.sim:
            from app.sim.part import ensure_features

            ensure_features(state.root, cfg)
        journal = Journal(state.commission, setup)
        if journal.next_step() is None:
            say(f"commissioned already: {state.commission_report}")
            return _finish(journal, args.json, 0)
        ctx = _context(args, cfg, state, seed, confirm, say, stack)
        return _run(ctx, journal, args.json, say)


def _context(
    args: argparse.Namespace,
    cfg: Any,
    state: Any,
    seed: int,
    confirm: Any,
    say: Any,
    stack: ExitStack,
) -> Any:
    from app.commission.context import Context

    sim = None
    urls = cfg.devices.urls()
    if args.sim:
        from app.sim.commission import SimCommissioning
        from app.sim.line_run import with_simulated_plc

        sim = stack.enter_context(
            SimCommissioning(cfg, seed, geometric=args.geometric, waiting=say_waiting)
        )
        urls = sim.urls
        cfg = with_simulated_plc(cfg)
    trace = cfg.devices.wire_trace(state.wire_trace, every_device=True if sim else None)
    station = open_devices(cfg, urls, trace, stack)
    if sim is not None:
        sim.station = station
    return Context(
        cfg=cfg,
        state=state,
        station=station,
        confirm=confirm,
        say=say,
        sensor_file=args.sensor,
        sensor_data=args.sensor_data,
        targets_file=args.targets,
        **(sim.context_fields() if sim else real_fields(cfg, station)),
    )


def open_devices(cfg: Any, urls: dict[str, str], trace: Any, stack: ExitStack) -> Any:
    """The devices of a guided procedure (app.commission.context.open_station), closed with
    `stack`; a configuration error is bad input (exit 2), an unreachable device one line."""
    from app.commission.context import open_station
    from app.errors import RvisError
    from drivers.errors import DeviceConfigError, DeviceError

    try:
        station = open_station(cfg, urls, trace)
    except DeviceConfigError as exc:
        raise InputError(str(exc), file=cfg.source, field="devices") from exc
    except DeviceError as exc:
        raise RvisError(f"cannot open the devices: {type(exc).__name__}: {exc}") from exc
    stack.callback(station.close)
    return station


def real_fields(cfg: Any, station: Any) -> dict[str, Any]:
    """What a guided procedure's Context takes on a real cell: the sweep through camera and
    galvo, targets captured by the camera (the engineer places the spheres; no truth)."""
    from app.commission.capture import CameraCapture

    return {"sphere_sensor": _real_sensor(cfg, station), "capture": CameraCapture()}


def _real_sensor(cfg: Any, station: Any) -> Any:
    from app.line.measure import SweepSensor
    from app.line.settings import from_cell

    def factory(model: Any) -> Any:
        if station.camera is None or station.galvo is None:
            raise InputError("measuring needs a camera and a galvo", field="devices")
        return SweepSensor(station.camera, station.galvo, model, from_cell(cfg).sweep)

    return factory


def _run(ctx: Any, journal: Any, as_json: bool, say: Any) -> int:
    from app.commission.context import Declined
    from app.commission.sequence import run_sequence

    try:
        failed = run_sequence(ctx, journal)
    except Declined as exc:
        say(f"stopped: not confirmed: {exc}; run `rvis commission` again to continue")
        return _finish(journal, as_json, 1)
    if failed is not None:
        say(f"step {failed} failed its checks: fix the cause and run `rvis commission` again")
        return _finish(journal, as_json, 3)
    say(f"commissioned: {ctx.state.root} is ready: {journal.steps['ready'].results['run']}")
    return _finish(journal, as_json, 0)


def _finish(journal: Any, as_json: bool, code: int) -> int:
    """The report written; its JSON printed (`--json`), else its headline and where it is."""
    from app.commission.report import counts_text, headline, headline_lines, to_json, write_report
    from app.formats.files import dumps_json

    md, _ = write_report(journal)
    if as_json:
        print(dumps_json(to_json(journal), indent=2))
    else:
        print(counts_text(journal))
        for line in headline_lines(headline(journal))[2:-1]:  # the bullets, as plain text
            print(line.replace("**", "").replace("`", ""))
        print(f"report: {md}")
    return code


def _printer(stream: Any) -> Any:
    def say(text: str) -> None:
        print(text, file=stream, flush=True)

    return say


def _confirmation(yes: bool, say: Any) -> Any:
    if yes:

        def confirm_all(question: str) -> bool:
            say(f"  {question} yes (--yes)")
            return True

        return confirm_all
    if not sys.stdin.isatty():
        raise InputError("confirming each step and motion needs a terminal (or --yes)")

    def ask(question: str) -> bool:
        try:
            answer = input(f"  {question} [y/N] ")
        except EOFError:
            return False
        return answer.strip().lower() in ("y", "yes")

    return ask
