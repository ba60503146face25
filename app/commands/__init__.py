"""One module per `rvis` subcommand; each exposes `register(subparsers)`.

The command line (app/cli.py) imports the modules listed in COMMANDS, in order. A command's
`register` adds its parser and sets `func(args) -> int` as the default handler.
"""

COMMANDS: tuple[str, ...] = (
    "demo",
    "simulate",
    "identify",
    "validate",
    "observability",
    "plan",
    "experiment",
    "devices",
    "sensor",
    "compensate",
    "export",
)
