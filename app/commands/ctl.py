"""`rvis ctl ACTION [...]`: send an operator's command to the running in-line service over its
control socket (the service writes it to its audit log with the caller's uid).

    rvis ctl pause | resume | reset | recalibrate
    rvis ctl approve [CALIBRATION] | reject [CALIBRATION]
    rvis ctl rollback VERSION | ack ALARM | shelve ALARM REASON [--minutes M]
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from app.commands import add_command
from app.errors import RvisError


def register(sub: Any) -> None:
    p = add_command(sub, "ctl")
    p.add_argument("--cell", help="cell configuration TOML (for [service] state_dir)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    p.add_argument("--json", action="store_true", help="print the reply as JSON")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, text in (
        ("pause", "measure no more windows until resumed"),
        ("resume", "measure again"),
        ("reset", "clear a fault (after the cause is removed)"),
        ("recalibrate", "recalibrate as soon as the rolling set is complete"),
    ):
        actions.add_parser(name, help=text)
    for name in ("approve", "reject"):
        a = actions.add_parser(name, help=f"{name} the pending calibration")
        a.add_argument("calibration", type=int, nargs="?", help="its id (default: the pending)")
    actions.add_parser("rollback", help="put an earlier parameters version in force").add_argument(
        "version", type=int
    )
    actions.add_parser("ack", help="acknowledge an alarm").add_argument("alarm", type=int)
    shelve = actions.add_parser("shelve", help="shelve an alarm for a while, with a reason")
    shelve.add_argument("alarm", type=int)
    shelve.add_argument("reason")
    shelve.add_argument("--minutes", type=float, default=60.0)
    p.set_defaults(func=run)


def request_args(args: argparse.Namespace) -> dict[str, Any]:
    keys = {
        "approve": ("calibration",),
        "reject": ("calibration",),
        "rollback": ("version",),
        "ack": ("alarm",),
        "shelve": ("alarm", "reason", "minutes"),
    }
    return {k: getattr(args, k) for k in keys.get(args.action, ()) if getattr(args, k) is not None}


def run(args: argparse.Namespace) -> int:
    from app.commands.status import state_dir_of
    from app.line.control import ControlClient
    from app.line.statedir import StateDir

    path = StateDir(state_dir_of(args)).socket
    try:
        with ControlClient(path) as client:
            reply = client.request(args.action, request_args(args))
    except (FileNotFoundError, ConnectionRefusedError) as exc:
        raise RvisError(f"no service is running at {path}") from exc
    except PermissionError as exc:
        raise RvisError(f"not allowed to use {path} (the service's group)") from exc
    except OSError as exc:  # the service went away meanwhile, or did not answer in time
        raise RvisError(f"{path}: no answer from the service ({exc.strerror or exc})") from exc
    if args.json:
        print(json.dumps(reply))
    elif reply.get("ok"):
        print(reply.get("message", "ok"))
    else:
        raise RvisError(str(reply.get("error")))
    return 0 if reply.get("ok") else 1
