"""`rvis demo`: the simulated cell end to end, no configuration file needed."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from app.config import load_cell
from app.demo import run_demo, summary_text
from app.planning import ProgressLine
from app.report import parameter_table


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate, identify, validate and report on the simulated cell")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell (default 0)")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--out", help="run folder (default runs/demo-<time>)")
    p.add_argument("--validation", type=int, default=100, help="validation positions (100)")
    p.add_argument(
        "--placement",
        choices=("fixed", "sequential", "joint", "none"),
        default="fixed",
        help="also calibrate with planned configurations: at the cell's sphere positions "
        "(fixed, default), with the spheres placed by PSO one by one as in the paper "
        "(sequential) or jointly; none: random configurations only",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/demo-{time.strftime('%Y%m%d-%H%M%S')}")
    print(f"rvis demo: simulated cell, seed {args.seed}; running ...", flush=True)
    placement = None if args.placement == "none" else args.placement
    demo = run_demo(
        cfg, args.seed, out, args.validation, placement, progress=ProgressLine(sys.stderr)
    )
    print(parameter_table(cfg.model(), demo.result))
    print()
    print(summary_text(demo))
    print(
        f"\nReport written to {out}/ (report.md, report.json, params.json, "
        f"validation_errors.png, CSV files) in {demo.seconds:.1f} s"
    )
    return 0
