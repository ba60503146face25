"""What the commands of the guided procedures share: `rvis commission`, `rvis maintain` and
`rvis sensor verify` (the commissioning's acceptance step alone).

How the engineer is told (`printer`) and asked (`confirmation`), the devices a procedure opens
(`open_devices`, `real_fields`, a guided procedure's Context fields: `guided_fields`, and the
commissioning's whole Context: `commissioning_context`),
the run of a procedure's steps (`run_procedure`) and its report at the end (`finish`). The
procedures themselves are app/commission/ and app/maintain/; each command keeps its own
arguments, its own Context and the line it says when every step passed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any, TextIO

from app.commands.args import say_waiting
from app.errors import InputError

if TYPE_CHECKING:
    from app.commission.context import Context
    from app.commission.journal import Journal

Say = Callable[[str], None]
Confirm = Callable[[str], bool]


def printer(stream: TextIO) -> Say:
    """How a procedure tells the engineer: each line printed to `stream` at once (stderr under
    `--json`, so that stdout holds the report's JSON alone)."""

    def say(text: str) -> None:
        print(text, file=stream, flush=True)

    return say


def confirmation(yes: bool, say: Say) -> Confirm:
    """How a procedure asks the engineer before each step and motion: with `--yes`, every
    question is said with its answer "yes (--yes)"; else a `[y/N]` prompt on the terminal, yes
    only for "y" or "yes" (end of input is a no). Without a terminal, `--yes` is needed (bad
    input, exit 2)."""
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


def run_procedure(
    ctx: Context,
    journal: Journal,
    as_json: bool,
    say: Say,
    *,
    command: str,
    done: Callable[[Context, Journal], str],
) -> int:
    """Runs the procedure's steps from the first one not passed (app.commission.sequence),
    then `finish`es with its exit code: 1 when the engineer declined a step or a motion, 3 when
    a step failed its checks (each said with `command`, e.g. "rvis commission", to run again),
    0 when every step passed, after the line `done(ctx, journal)` gives."""
    from app.commission.context import Declined
    from app.commission.sequence import run_sequence

    try:
        failed = run_sequence(ctx, journal)
    except Declined as exc:
        say(f"stopped: not confirmed: {exc}; run `{command}` again to continue")
        return finish(journal, as_json, 1)
    if failed is not None:
        say(f"step {failed} failed its checks: fix the cause and run `{command}` again")
        return finish(journal, as_json, 3)
    say(done(ctx, journal))
    return finish(journal, as_json, 0)


def finish(journal: Journal, as_json: bool, code: int) -> int:
    """The report written; its JSON printed (`--json`), else its headline and where it is;
    `code` returned (the command's exit code)."""
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


def commissioning_context(
    args: argparse.Namespace,
    cfg: Any,
    state: Any,
    seed: int,
    confirm: Confirm,
    say: Say,
    stack: ExitStack,
) -> Context:
    """The commissioning's Context, its devices opened (closed with `stack`): the simulated
    line's (`args.sim`, `args.geometric`, on `seed`) or the cell's own; `args.sensor`,
    `args.sensor_data` and `args.targets` as given."""
    from app.commission.context import Context

    fields = guided_fields(args, cfg, state, seed, args.geometric, confirm, say, stack)
    return Context(**fields)


def guided_fields(
    args: argparse.Namespace,
    cfg: Any,
    state: Any,
    seed: int,
    geometric: bool,
    confirm: Confirm,
    say: Say,
    stack: ExitStack,
    *,
    every_device_traced: bool = True,
    **sim_world: Any,
) -> dict[str, Any]:
    """A guided procedure's Context fields (the commissioning's, a maintenance's), its devices
    opened (closed with `stack`): the simulated line's (`args.sim`, on `seed`, `geometric`;
    `sim_world`: where its world continues, SimCommissioning's world_s, start_epoch, world) or
    the cell's own; the simulated line's wire trace of every device or of none
    (`every_device_traced`); `args.sensor`, `args.sensor_data` and `args.targets` as given."""
    sim = None
    urls = cfg.devices.urls()
    if args.sim:
        from app.sim.commission import SimCommissioning
        from app.sim.line_setup import with_simulated_plc

        sim = stack.enter_context(
            SimCommissioning(cfg, seed, geometric=geometric, waiting=say_waiting, **sim_world)
        )
        urls = sim.urls
        cfg = with_simulated_plc(cfg)
    trace = None
    if every_device_traced:
        trace = cfg.devices.wire_trace(state.wire_trace, every_device=True if sim else None)
    station = open_devices(cfg, urls, trace, stack)
    if sim is not None:
        sim.station = station
    return {
        "cfg": cfg,
        "state": state,
        "station": station,
        "confirm": confirm,
        "say": say,
        "sensor_file": args.sensor,
        "sensor_data": args.sensor_data,
        "targets_file": args.targets,
        **(sim.context_fields() if sim else real_fields(cfg, station)),
    }


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
