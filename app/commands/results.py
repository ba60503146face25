"""`rvis results list|show BODY|export`: the bodies' results from the state database, read-only
(the service may run). What each value is and how sure (its U95), its decision, whether it is
suspect; `export` writes them as AQDEF (`.dfq`, app/formats/aqdef.py: the station from the cell
file's `[results]`, the part's description from the feature plan), JSON (a record per body) or
CSV (a row per value), to stdout or atomically into a folder.

    rvis results list [--since T] [--json]
    rvis results show BODY [--json]
    rvis results capability [--last 50] [--json]
    rvis results export [--since T] [--body ID] --format dfq|csv|json [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.commands.args import int_at_least
from app.commands.state import parse_since, state_dir_of
from app.errors import InputError


def register(sub: Any) -> None:
    p = add_command(sub, "results")
    p.add_argument("--cell", help="cell configuration TOML (for [service] state_dir)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", parser_class=type(p))
    verbs.required = True
    since = "bodies measured at or after this UTC time (2026-11-25T06:00:00) or age (8h, 2d)"
    ls = verbs.add_parser("list", help="the bodies measured, a line each")
    ls.add_argument("--since", help=since)
    ls.add_argument("--json", action="store_true", help="print the records as JSON")
    show = verbs.add_parser("show", help="one body's values, their U95 and decisions")
    show.add_argument("body", help="the body's id (as the PLC gave it)")
    show.add_argument("--json", action="store_true", help="print the record as JSON")
    cap = verbs.add_parser("capability", help="Cp and Cpk per characteristic over the last bodies")
    cap.add_argument("--last", type=int_at_least(2), default=50, help="bodies (50)")
    cap.add_argument("--json", action="store_true", help="print the figures as JSON")
    ex = verbs.add_parser("export", help="the values as JSON or CSV")
    ex.add_argument("--since", help=since)
    ex.add_argument("--body", help="one body's id")
    ex.add_argument("--format", choices=("dfq", "csv", "json"), required=True)
    ex.add_argument(
        "--out", type=Path, help="folder to write results.<format> into (default: stdout)"
    )
    p.set_defaults(func=run)


def _records(args: argparse.Namespace) -> list[dict[str, Any]]:
    from app.line.body_results import records
    from app.line.statedir import StateDir
    from app.line.store import Store

    state = StateDir(state_dir_of(args))
    if not state.db.is_file():
        raise InputError("no service state here (no rvis.db)", file=state.root)
    now = time.time()
    since = None if getattr(args, "since", None) is None else parse_since(args.since, now)
    body = getattr(args, "body", None)
    store = Store.read_only(state.db)
    try:
        return records(store, since, body, now)
    finally:
        store.close()


def run(args: argparse.Namespace) -> int:
    recs = _records(args)
    if args.verb == "list":
        print(json.dumps(recs, indent=1) if args.json else _list_text(recs))
        return 0
    if args.verb == "capability":
        from app.line.body_results import capability

        rows = capability(recs[-args.last :])
        print(json.dumps(rows, indent=1) if args.json else _capability_text(rows, args.last))
        return 0
    if args.verb == "show":
        if not recs:
            raise InputError(f"no body {args.body!r} measured here", field="BODY")
        from app.line.body_results import show_text

        print(json.dumps(recs[-1], indent=1) if args.json else show_text(recs[-1]))
        return 0
    return _export(args, recs, args.format, args.out)


def _dfq(args: argparse.Namespace, recs: list[dict[str, Any]]) -> str:
    """The records as one AQDEF file: the station from the cell file, the description from
    the feature plan of the state directory."""
    from app.config import load_cell
    from app.config.tomlfile import read_toml
    from app.formats.aqdef import dfq_text
    from app.line.statedir import StateDir

    if not recs:
        raise InputError("no body to export (an AQDEF file holds at least one)", field="--since")
    state = StateDir(state_dir_of(args))
    cell = args.cell or (str(state.cell) if state.cell.is_file() else None)
    r = load_cell(cell).results
    plan = state.features
    description = str(read_toml(plan)[0].get("description", "")) if plan.is_file() else ""
    return dfq_text(recs[0]["part"], description, recs, (r.station, r.station_description))


def _export(
    args: argparse.Namespace, recs: list[dict[str, Any]], fmt: str, out: Path | None
) -> int:
    from app.formats.files import write_text
    from app.line.body_results import csv_text

    if fmt == "dfq":
        text = _dfq(args, recs)
    else:
        text = csv_text(recs) if fmt == "csv" else json.dumps(recs, indent=1) + "\n"
    if out is None:
        sys.stdout.write(text)
        return 0
    if out.exists() and not out.is_dir():
        raise InputError("not a folder", file=out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"results.{fmt}"
    write_text(path, text)
    print(f"written {path}: {len(recs)} bodies")
    return 0


def _capability_text(rows: list[dict[str, Any]], last: int) -> str:
    if not rows:
        return "no body measured"
    lines = [
        f"over the last {last} bodies (values measured and not suspect):",
        f"{'characteristic':<14} {'n':>4} {'mean':>11} {'sd':>7} {'Cp':>6} {'Cpk':>6}",
    ]
    for r in rows:
        key = f"{r['feature']}.{r['characteristic']}"
        sd, cp, cpk = (f"{r[k]:.{d}f}" if r[k] is not None else "-"
                       for k, d in (("sd_mm", 3), ("cp", 2), ("cpk", 2)))  # fmt: skip
        lines.append(f"{key:<14} {r['n']:>4} {r['mean_mm']:>11.3f} {sd:>7} {cp:>6} {cpk:>6}")
    return "\n".join(lines)


def _list_text(recs: list[dict[str, Any]]) -> str:
    if not recs:
        return "no body measured"
    lines = [f"{'body':<12} {'time (UTC)':<25} {'result':<6} nok und  nm version  note"]
    for r in recs:
        note = []
        if r["reevaluated"]:
            note.append(f"computed again (evaluation {r['evaluation']})")
        if r["suspect_interval"] is not None:
            note.append(f"suspect (interval {r['suspect_interval']})")
        lines.append(
            f"{r['body']!s:<12} {r['time_utc']:<25} {'OK' if r['ok'] else 'NOK':<6}"
            f" {r['n_nok']:>3} {r['n_undecided']:>3} {r['n_not_measured']:>3}"
            f" {r['params_version']!s:>7}  {'; '.join(note)}"
        )
    return "\n".join(lines)
