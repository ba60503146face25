"""`rvis tui [--state-dir DIR] [--cell cell.toml]`: the operator's terminal, attached to the
service of a state directory (its control socket and, read-only, its database). Closing it
never stops the service.

`rvis tui --sim [--rendered] [--seed N]`: first start the simulated line and its service in this
process (geometric measurements unless --rendered, app/sim/tui_line.py), then attach; closing the
terminal stops that simulated service. Its log lines go to STATE_DIR/rvis-sim.log. On the
geometric path the line measures the simulated part type's bodies (its feature plan written to
the state directory when it has none: the Bodies pane shows them); a rendered body's sweeps
would hold the service for minutes a body, so --rendered measures the bodies only of a plan
already there."""

from __future__ import annotations

import argparse

from app.commands import add_command
from app.commands.args import int_at_least


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "tui")
    p.add_argument("--state-dir", help="the service's state directory (default: [service])")
    p.add_argument("--cell", help="cell configuration TOML (for the default state directory)")
    p.add_argument("--sim", action="store_true", help="run a simulated line and service here")
    p.add_argument(
        "--geometric",
        action="store_true",
        default=True,
        help="--sim: geometric measurements, no rendering (the default)",
    )
    p.add_argument("--rendered", action="store_true", help="--sim: render and grab every frame")
    p.add_argument("--seed", type=int_at_least(0), help="--sim: seed (default [simulation])")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from app.config import load_cell
    from app.errors import InputError
    from app.tui.app import RvisTui

    cfg = load_cell(args.cell)
    state_dir = Path(args.state_dir or cfg.service.state_dir)
    if not args.sim:
        if args.rendered or args.seed is not None:
            raise InputError("--rendered and --seed need --sim")
        RvisTui(state_dir).run()
        return 0
    import logging

    from app.line.launch import json_logs
    from app.line.statedir import StateDir
    from app.sim.tui_line import TuiSimSettings, simulated_service

    settings = TuiSimSettings(geometric=not args.rendered, seed=args.seed)
    state_dir.mkdir(parents=True, exist_ok=True)
    if settings.geometric:
        from app.sim.part import ensure_features

        ensure_features(state_dir, cfg)
    # the service's log lines go to a file: on the terminal they would draw over the screen
    with open(StateDir(state_dir).sim_log, "a") as log:
        handler = json_logs(log)
        try:
            with simulated_service(cfg, state_dir, settings):
                RvisTui(state_dir).run()
        finally:
            logging.getLogger("rvis").removeHandler(handler)
    return 0
