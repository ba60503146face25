"""The `rvis` command line: parses arguments, runs one subcommand, turns user errors into a
one-line message and exit code 2 (never a traceback for a user mistake).

Only the chosen command's module is imported (the others are listed from
app.commands.COMMANDS), so `rvis --help` starts fast and loads no numerical library.
"""

from __future__ import annotations

import argparse
import copy
import importlib
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn

from app.commands import COMMANDS
from app.errors import RvisError


def _chosen(argv: Sequence[str]) -> str | None:
    """The subcommand named in argv (the first word that is neither an option nor the value of
    `--log-level`), if any."""
    words = iter(argv)
    for word in words:
        if word == "--log-level":
            next(words, None)
        elif not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def _version() -> str:
    from app.meta import software_revision

    return f"rvis {software_revision()}"


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (`rvis identify: error: ...`), exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _VersionAction(argparse.Action):
    def __init__(self, option_strings: Sequence[str], dest: str, **kw: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: object, **kw: object) -> None:
        print(_version())
        parser.exit()


def build_parser(argv: Sequence[str] = ()) -> argparse.ArgumentParser:
    parser = _Parser(
        prog="rvis",
        description="In-line self-calibration of a robotic visual inspection system.",
    )
    parser.add_argument("--version", action=_VersionAction)
    _add_log_level(parser, "off")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    chosen = _chosen(argv)
    for name, help_text in COMMANDS.items():
        if name == chosen:
            importlib.import_module(f"app.commands.{name}").register(sub)
            _add_log_level(sub.choices[name], argparse.SUPPRESS)  # also after the command's name
            share_options(sub.choices[name])
        else:
            sub.add_parser(name, help=help_text, add_help=False)
    return parser


def command_parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """`parser` and the parsers of its sub-commands (`rvis experiment shift`, ...)."""
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                found += command_parsers(child)
    return found


def share_options(parser: argparse.ArgumentParser) -> None:
    """Every option of `parser` is also an option of each of its verbs, and so on down: an
    option of a command applies to all its verbs and may stand before or after the verb
    (`rvis ctl pause --state-dir S` reads as `rvis ctl --state-dir S pause`).

    The verb's copy defaults to SUPPRESS: argparse copies a verb's namespace over the
    command's, so a real default there would reset the value given before the verb. An option
    declared on a command and again on one of its verbs would have two homes: refused."""
    options = [a for a in parser._actions if a.option_strings and a.dest != "help"]
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        for verb in action.choices.values():
            have = {s for a in verb._actions for s in a.option_strings}
            for option in options:
                if have & set(option.option_strings):
                    raise ValueError(f"{verb.prog}: {option.option_strings[0]} is {parser.prog}'s")
                shared = copy.copy(option)
                shared.default = argparse.SUPPRESS
                verb._add_action(shared)
            share_options(verb)


def _add_log_level(parser: argparse.ArgumentParser, default: str) -> None:
    from app.commands.logs import LEVELS

    parser.add_argument(
        "--log-level",
        choices=LEVELS,
        default=default,
        help="log records of this level and above as text lines on stderr (default: off; "
        "alarms are in the command's summary, the service logs JSON lines on stdout)",
    )


def main(argv: Sequence[str] | None = None) -> int:
    from app.threads import limit_blas_threads

    limit_blas_threads()
    if argv is None:
        argv = sys.argv[1:]
        # `rvis ... | head`: a closed pipe ends the process quietly, as for any Unix tool
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    args = build_parser(argv).parse_args(argv)
    from app.commands.logs import configure

    configure(args.log_level)
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
