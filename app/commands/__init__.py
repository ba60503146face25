"""One module per `rvis` subcommand; each exposes `register(subparsers)`.

COMMANDS lists every subcommand with its one-line help, in the order `rvis --help` shows them;
it is the help's only home: a command's `register` adds its parser with `add_command`.
The command line (app/commands/cli.py; `python -m app`) imports only the module of the command
being run (so `rvis --help` imports none of numpy, OpenCV or the fakes); a command's `register`
adds its parser and sets `func(args) -> int` as the default handler.

A command with verbs (`rvis ctl pause`, `rvis state check`) declares the options every verb
takes once, on the command's parser; the command line gives each verb a copy
(cli.share_options), so they may stand before or after the verb. An option of one verb alone
goes on that verb's parser.
"""

from __future__ import annotations

import argparse
from typing import Any

COMMANDS: dict[str, str] = {
    "demo": "simulate, identify, validate and report on the simulated cell",
    "simulate": "write simulated calibration and validation sets",
    "identify": "identify the kinematic parameters from measurements",
    "validate": "errors of a parameter set at validation positions",
    "observability": "rank, condition and O1..O5 of measurements",
    "plan": "plan sphere positions (PSO) and measurement configurations (DETMAX)",
    "experiment": "experiments on the simulated cell (paper, accuracy, shift, gauge studies, ...)",
    "compensate": "compensated joint targets for the controller (CSV or .ls)",
    "export": "export the identified calibration (URDF)",
    "devices": "check the configured devices; run the simulated line's",
    "sensor": "laser-line sensor: calibrate, measure",
    "commission": "guided, resumable commissioning of a cell",
    "maintain": "guided procedure after maintenance: a sensor, an axis, a fixture",
    "run": "the unattended in-line service",
    "status": "state of the in-line service",
    "ctl": "send a command to the in-line service",
    "tui": "the operator's terminal of a running service",
    "state": "back up, restore, check the state directory; list suspect intervals",
    "inspect": "the body: a view per feature of the part type and a route",
    "results": "the bodies' results: list, one body's values, export as JSON or CSV",
}


def add_command(sub: argparse._SubParsersAction, name: str, **kw: Any) -> argparse.ArgumentParser:
    """The parser of command `name`, with its help from COMMANDS (also its description)."""
    parser: argparse.ArgumentParser = sub.add_parser(
        name, help=COMMANDS[name], description=kw.pop("description", COMMANDS[name]), **kw
    )
    return parser
