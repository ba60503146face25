"""`rvis tui [--state-dir DIR] [--cell cell.toml]`: the operator's terminal, attached to the
service of a state directory (its control socket and, read-only, its database). Closing it
never stops the service."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tui", help="the operator's terminal of a running service")
    p.add_argument("--state-dir", help="the service's state directory (default: [service])")
    p.add_argument("--cell", help="cell configuration TOML (for the default state directory)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.config import load_cell
    from app.tui.app import RvisTui

    state_dir = args.state_dir or load_cell(args.cell).service.state_dir
    RvisTui(state_dir).run()
    return 0
