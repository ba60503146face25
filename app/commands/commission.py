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
from app.commands.args import int_at_least
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
    from app.commands.guided import (
        commissioning_context,
        confirmation,
        finish,
        printer,
        run_procedure,
    )
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
    say = printer(sys.stderr if args.json else sys.stdout)
    confirm = confirmation(args.yes, say)
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
            return finish(journal, args.json, 0)
        ctx = commissioning_context(args, cfg, state, seed, confirm, say, stack)
        return run_procedure(
            ctx, journal, args.json, say, command="rvis commission", done=_commissioned
        )


def _commissioned(ctx: Any, journal: Any) -> str:
    """The line `rvis commission` says when every step passed."""
    return f"commissioned: {ctx.state.root} is ready: {journal.steps['ready'].results['run']}"
