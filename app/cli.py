"""The `rvis` command line: parses arguments, runs one subcommand, turns user errors into a
one-line message and exit code 2 (never a traceback for a user mistake)."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from app.commands import COMMANDS
from app.errors import RvisError


class _Parser(argparse.ArgumentParser):
    """argparse exits with 2 on usage errors already; keep its one-line message."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="rvis",
        description="In-line self-calibration of a robotic visual inspection system.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"app.commands.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except RvisError as exc:
        print(f"rvis {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"rvis {args.command}: interrupted", file=sys.stderr)
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())
