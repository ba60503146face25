"""`rvis experiment gauge` and `rvis experiment correlation`: the body's gauge studies on the
simulated line (app/sim/inspection.py), writing DIR/gauge.json or DIR/correlation.json."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from app.commands.args import int_at_least
from app.config import load_cell
from app.errors import InputError

#: the in-line service's windows before the bodies: two hours of the simulated line, past its
#: first in-line recalibrations of the compliant model
LINE_WINDOWS = 120
STUDIES = {
    "gauge": "type-1 study of the body's characteristics on one master body (Cg, Cgk)",
    "correlation": "the body's values in-line against the simulated CMM, no offsets",
}


def add_options(p: argparse.ArgumentParser, name: str) -> None:
    p.add_argument("--seed", type=int_at_least(0), default=0, help="the cell's seed (0)")
    if name == "gauge":
        p.add_argument(
            "--repeats", type=int_at_least(2), default=50, help="measurements of the master (50)"
        )
    else:
        p.add_argument("--bodies", type=int_at_least(2), default=50, help="bodies measured (50)")
        p.add_argument(
            "--knock",
            choices=("sensor", "fixture", "joint"),
            help="knock the cell (the service finds and corrects it; its bodies are computed"
            " again)",
        )
        p.add_argument(
            "--knock-at-h", type=float, default=2.5, help="the knock's hour of the line (2.5)"
        )
    p.add_argument(
        "--geometric",
        action="store_true",
        help="the geometric sensor path (default: rendered, spheres and bodies: slow, a small run)",
    )
    p.add_argument(
        "--line-windows",
        type=int_at_least(0),
        default=LINE_WINDOWS,
        help="windows the in-line service runs on the commissioned cell before the bodies are"
        f" measured ({LINE_WINDOWS}: about 2 h of the line; 0: the commissioning's parameters)",
    )
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--out", required=True, help="output folder (a new one; state/ holds the cell)")


def run_study(args: argparse.Namespace) -> int:
    from app.formats.files import write_json
    from app.formats.jsontext import dumps_json
    from app.sim.inspection import LineStudy, inspection_cell, run_correlation, run_gauge

    if args.name == "correlation" and not (math.isfinite(args.knock_at_h) and args.knock_at_h > 0):
        raise InputError("the knock's hour must be > 0", field="--knock-at-h")
    cfg = load_cell(args.cell)
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError("the output folder is not empty", file=out)
    out.mkdir(parents=True, exist_ok=True)

    def progress(text: str) -> None:
        print(f"  {text}", file=sys.stderr, flush=True)

    print(
        f"rvis experiment {args.name}: seed {args.seed}, the cell commissioned and run for"
        f" {args.line_windows} windows, {'geometric' if args.geometric else 'rendered'} path",
        file=sys.stderr,
    )
    if args.name == "gauge":
        with inspection_cell(cfg, args.seed, out, args.line_windows, None, args.geometric) as cell:
            doc = run_gauge(cell, args.repeats, progress)
    else:
        study = LineStudy(
            args.bodies, args.line_windows, args.knock, args.knock_at_h, args.geometric
        )
        doc = run_correlation(cfg, args.seed, out, study, progress)
    path = out / f"{args.name}.json"
    write_json(path, doc)
    print(dumps_json(doc["summary"], indent=2))
    print(f"written {path}")
    return 0
