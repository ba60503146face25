"""`rvis maintain sensor|axis N|fixture [--state-dir DIR] [--yes] [--restart] [--sensor FILE |
--sensor-data DIR] [--targets FILE] [--json]`, `... --sim [--seed N]`: the guided, resumable
procedure after maintenance on a commissioned cell (app/maintain/, docs/maintenance.md).

Like `rvis commission`, each step and every motion waits for the engineer's yes (`--yes` for
a scripted run), the results and the report go to STATE_DIR/maintenance/NNNN-<event>/, and run
again it continues at the first step not passed. The service must be stopped (the state
directory's lock). Exit 0 when the cell is handed back to `rvis run`, 3 when a step failed its
checks, 1 when the engineer stopped it, 2 on bad input.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.args import int_at_least, sim_seed
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "maintain")
    p.add_argument("event", choices=("sensor", "axis", "fixture"), help="what was done")
    p.add_argument("axis", nargs="?", type=int_at_least(1), help="axis: its number (1-6)")
    p.add_argument("--state-dir", type=Path, help="state directory (default: [service])")
    p.add_argument("--cell", type=Path, help="cell file (default: the state directory's)")
    p.add_argument("--yes", action="store_true", help="confirm every step and motion")
    p.add_argument("--restart", action="store_true", help="begin this procedure again")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--sensor", type=Path, help="sensor: its calibration made elsewhere")
    source.add_argument("--sensor-data", type=Path, help="sensor: targets recorded earlier")
    spheres = p.add_mutually_exclusive_group()
    spheres.add_argument(
        "--targets", type=Path, help="fixture: the tracker's export of the spheres"
    )
    spheres.add_argument(
        "--no-tracker",
        action="store_true",
        help="fixture: no tracker at hand (the spheres located by the robot, not validated)",
    )
    p.add_argument("--sim", action="store_true", help="on the simulated line (no hardware)")
    p.add_argument("--seed", type=int_at_least(0), help="--sim: the commissioned seed")
    p.add_argument("--json", action="store_true", help="print the report as JSON at the end")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.commands.guided import confirmation, finish, printer, run_procedure
    from app.config import load_cell
    from app.line.launch import hold_state
    from app.line.statedir import StateDir

    axis = _axis(args)
    for path in (args.sensor, args.targets):
        if path is not None and not path.is_file():
            raise InputError("file not found", file=path)
    if args.sensor_data is not None and not args.sensor_data.is_dir():
        raise InputError("folder not found", file=args.sensor_data)
    if args.seed is not None and not args.sim:
        raise InputError("--seed needs --sim")
    if args.no_tracker and args.event != "fixture":
        raise InputError("--no-tracker is for a fixture renewed (`rvis maintain fixture`)")
    state_dir = args.state_dir or Path(load_cell(args.cell).service.state_dir)
    paths = StateDir(state_dir)
    if not paths.cell.is_file():
        raise InputError(
            "not a commissioned state directory (no cell.toml): run `rvis commission` first",
            file=state_dir,
        )
    cfg = load_cell(args.cell or paths.cell)
    say = printer(sys.stderr if args.json else sys.stdout)
    confirm = confirmation(args.yes, say)
    setup: dict[str, Any] = {"event": args.event, "axis": axis, "simulated": args.sim}
    if args.sim:
        setup["seed"] = sim_seed(args.seed, cfg, paths.cell)
    with hold_state(state_dir, str(cfg.service.operators_group)) as state, ExitStack() as stack:
        from app.commission.journal import Journal
        from app.maintain.record import open_record
        from app.maintain.table import procedure

        t = _now(args.sim, state)
        folder, record = open_record(state, args.event, axis, restart=args.restart, t=t, say=say)
        journal = Journal(folder, setup, procedure(args.event, axis))
        if journal.next_step() is None:
            say(f"handed back already: {folder}")
            return finish(journal, args.json, 0)
        ctx = _context(args, cfg, state, setup, axis, record, folder, confirm, say, stack)
        return run_procedure(
            ctx, journal, args.json, say, command="rvis maintain", done=_handed_back
        )


def _axis(args: argparse.Namespace) -> int | None:
    if args.event == "axis":
        if args.axis is None or not 1 <= args.axis <= 6:
            raise InputError("rvis maintain axis needs the axis's number, 1..6", field="axis")
        return int(args.axis)
    if args.axis is not None:
        raise InputError(f"rvis maintain {args.event} takes no axis number", field="axis")
    return None


def _now(sim: bool, state: Any) -> float:
    """The time now: the wall clock's, or the simulated line's continued past its history."""
    if not sim:
        return datetime.now(UTC).timestamp()
    from app.sim.line_setup import continued_epoch

    return continued_epoch(state.root)[0]


def _context(
    args: argparse.Namespace,
    cfg: Any,
    state: Any,
    setup: dict[str, Any],
    axis: int | None,
    record: int,
    folder: Path,
    confirm: Any,
    say: Any,
    stack: ExitStack,
) -> Any:
    """The procedure's Context: the commissioning's fields (app.commands.guided), the
    simulated line's world continuing where the service left it."""
    from app.commands.guided import guided_fields
    from app.maintain.context import MaintenanceContext
    from app.maintain.fixture import without_tracker

    world: dict[str, Any] = {}
    if args.sim:
        from app.sim.line_setup import continued_epoch, world_of

        epoch, world_s = continued_epoch(state.root)
        world = {"world_s": world_s, "start_epoch": epoch, "world": world_of(cfg, state.root)}
    geometric = bool(cfg.simulation.geometric)
    fields = guided_fields(
        args, cfg, state, int(setup.get("seed", 0)), geometric, confirm, say, stack,
        every_device_traced=False, **world,
    )  # fmt: skip
    if args.no_tracker:
        fields = without_tracker(fields)
    return MaintenanceContext(
        **fields, out_dir=folder, event=args.event, axis=axis, record_id=record
    )


def _handed_back(ctx: Any, journal: Any) -> str:
    """The line `rvis maintain` says when every step passed (the cell handed back)."""
    run = journal.steps["handover"].results.get("run", "rvis run")
    return f"handed back: {ctx.state.root} is ready for `{run}`"
