"""`rvis state backup|restore|check|suspects|body`: the service's state directory as something
an operator can carry (docs/operations.md).

- `backup DEST`: a consistent copy while the service runs (SQLite's online backup of `rvis.db`,
  then what `StateDir.carried()` names: the parameter history, `current.json`, the plan, the
  commissioned `cell.toml` and `sensor.toml`, `commission/` and the OPC UA server's
  certificate, key and trusted clients), checked, with a `backup.json` manifest. The history
  is copied after the database, so it holds every version the copied database names.
- `restore BACKUP`: a backup into a state directory that no service holds and that has no
  database (a damaged one is moved aside by a person first: rvis never overwrites a database).
- `suspects [--since T] [--json]`: the suspect intervals (app/line/step.py): from the last
  trustworthy measurement before a step to the apply of its correction, when the calibration in
  force was wrong, with its estimated size and the bodies measured then (their ids as the line
  PLC gives them, `[line] plc_body_id`), for the inspection software to re-measure or flag.
- `body BODY [--json]`: how sure the measurement of one body is (app/commands/state_body.py):
  the window it was clamped in, the parameters version in force then, the U95 the cell stated
  for its bodies, the suspect intervals it falls in, and its values with their U95 when the
  cell measured it.
- `check`: read-only findings about a state directory (integrity, schema, parameters against the
  history and the database, the files the commissioning wrote, permissions, free space, the
  lock holder, the sizes); exit 1 when something is wrong. With an operators' group (`--cell`'s
  `[service] operators_group`, else the group of a setgid directory, as the service leaves it)
  files that do not follow it are a problem, with the one line that fixes them.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.state_backup import backup, backup_text, restore
from app.commands.state_check import check, check_report
from app.commands.status import state_dir_of
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "state")
    p.add_argument("--cell", help="cell configuration TOML (for [service] state_dir)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", parser_class=type(p))
    verbs.required = True
    b = verbs.add_parser("backup", help="copy the state while the service runs")
    b.add_argument("dest", help="new (or empty) folder for the copy")
    b.add_argument("--json", action="store_true", help="print the manifest as JSON")
    r = verbs.add_parser("restore", help="a backup into a state directory with no database")
    r.add_argument("backup", help="folder written by `rvis state backup`")
    c = verbs.add_parser("check", help="check a state directory (read-only)")
    c.add_argument("--json", action="store_true", help="print the findings as JSON")
    s = verbs.add_parser(
        "suspects", help="when the calibration in force was wrong after a step (read-only)"
    )
    s.add_argument(
        "--since",
        help="intervals open or ending at or after this UTC time (2026-11-25T06:00:00) or age"
        " (90m, 8h, 2d); default: all",
    )
    s.add_argument("--json", action="store_true", help="print the intervals as JSON")
    bd = verbs.add_parser("body", help="how sure the measurement of one body is (read-only)")
    bd.add_argument("body", help="the body's id (as the PLC gave it)")
    bd.add_argument("--json", action="store_true", help="print the answer as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.line.statedir import StateDir

    state = StateDir(state_dir_of(args))
    if args.verb == "backup":
        manifest = backup(state, Path(args.dest))
        print(json.dumps(manifest, indent=1) if args.json else backup_text(manifest, args.dest))
        return 0
    if args.verb == "suspects":
        since = None if args.since is None else parse_since(args.since, time.time())
        rows = suspects(state, since)
        print(json.dumps(rows, indent=1) if args.json else _suspects_table(rows))
        return 0
    if args.verb == "body":
        from app.commands.state_body import body_answer, body_text

        doc = body_answer(state, args.body, time.time())
        print(json.dumps(doc, indent=1) if args.json else body_text(doc))
        return 0
    if args.verb == "restore":
        restored = restore(Path(args.backup), state)
        print(f"restored {args.backup} into {state.root}")
        if restored.cell_named is not None:
            print(
                f"  cell.toml: [service] state_dir {restored.cell_named} -> {state.root.resolve()}"
            )
        return 0
    min_free_mb, group = _service_settings(args)
    findings = check(state, min_free_mb, group)
    if args.json:
        print(json.dumps(findings, indent=2))
    else:
        print(check_report(findings))
    return 0 if not findings["problems"] else 1


def _service_settings(args: argparse.Namespace) -> tuple[float, str | None]:
    """The cell file's [service] min_free_mb and operators_group; without `--cell` the
    default and None (no file loaded: the directory's own group is checked)."""
    if args.cell is None:
        from app.state_defaults import MIN_FREE_MB

        return MIN_FREE_MB, None
    from app.config import load_cell

    service = load_cell(args.cell).service
    return float(service.min_free_mb), str(service.operators_group)


# -- suspect intervals -------------------------------------------------------------------------
def parse_since(text: str, now: float) -> float:
    """`--since`: an ISO 8601 UTC time ("2026-11-25", "2026-11-25T06:00:00") or an age
    ("90m", "8h", "2d"); the Unix time it stands for. InputError naming the field otherwise."""
    units = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0}
    t = text.strip()
    if t[-1:] in units:
        try:
            age = float(t[:-1])
        except ValueError:
            age = -1.0
        if age >= 0 and math.isfinite(age):
            return now - age * units[t[-1]]
    try:
        when = datetime.fromisoformat(t)
    except ValueError:
        raise InputError(
            f"{text!r} is neither a UTC time (2026-11-25T06:00:00) nor an age (90m, 8h, 2d)",
            field="--since",
        ) from None
    return (when if when.tzinfo else when.replace(tzinfo=UTC)).timestamp()


def suspects(state: Any, since_t: float | None) -> list[dict[str, Any]]:
    """The suspect intervals of the state directory (open ones always, closed ones ending at or
    after `since_t`), as the service's events carry them (app.line.states.suspect_json)."""
    from app.line.states import suspect_json
    from app.line.store import Store

    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state.root)
    store = Store.read_only(state.db)
    try:
        return [suspect_json(r) for r in store.suspects(since_t)]
    finally:
        store.close()


def _suspects_table(rows: list[dict[str, Any]]) -> str:
    """One line per interval, then its bodies whole (wrapped), when the PLC names them."""
    import textwrap

    from app.line.states import bodies_text

    if not rows:
        return "no suspect intervals"
    lines = [f"{'id':>4}  {'from (UTC)':<25} {'to (UTC)':<25} {'size mm':>8}  {'bodies':<8}  what"]
    for r in rows:
        size = "-" if r["size_mm"] is None else f"{r['size_mm']:.3f}"
        bodies = r.get("bodies") or []
        lines.append(
            f"{r['id']:>4}  {r['start_utc']:<25} {r['end_utc'] or 'open':<25} {size:>8}"
            f"  {len(bodies):<8}  {r['text'] or ''}"
        )
        if bodies:
            text = f"bodies ({bodies_text(bodies)}): {', '.join(map(str, bodies))}"
            lines += textwrap.wrap(text, 96, initial_indent="      ", subsequent_indent="        ")
    return "\n".join(lines)
