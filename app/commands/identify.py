"""`rvis identify`: identify the 30 parameters from a measurements and a targets CSV."""

from __future__ import annotations

import argparse
import json

from app.config import load_cell
from app.dataio import as_input_error, load_dataset
from app.errors import InputError
from app.files import write_json
from app.params import to_json
from app.report import parameter_table
from calib.identify import LOSSES, identify
from calib.model import ALL_NAMES, PAPER_30


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("identify", help="identify the kinematic parameters from measurements")
    p.add_argument("--targets", required=True, help="targets CSV (tracker centres, part frame)")
    p.add_argument("--measurements", required=True, help="measurements CSV")
    p.add_argument("--out", required=True, help="parameters JSON to write")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--loss", default="linear", choices=LOSSES, help="robust loss (default linear)")
    p.add_argument(
        "--add-param",
        action="append",
        default=[],
        metavar="NAME",
        help="identify an extra model parameter too (e.g. d3)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_cell(args.cell)
    model = cfg.model()
    for name in args.add_param:
        if name not in ALL_NAMES:
            raise InputError(f"unknown model parameter '{name}'", field="--add-param")
        if name in PAPER_30:
            raise InputError(f"'{name}' is identified already", field="--add-param")
    active = (*PAPER_30, *args.add_param)
    data = load_dataset(args.measurements, args.targets, cfg.limits)
    result = as_input_error(
        args.measurements, lambda: identify(model, data, active=active, loss=args.loss)
    )
    doc = to_json(model, result)
    write_json(args.out, doc)
    if args.json:
        print(json.dumps({k: doc[k] for k in ("residuals", "rank", "condition", "success")}))
    else:
        print(parameter_table(model, result))
        print(
            f"\n{len(data)} measurements, residual RMS {result.rms_mm:.4f} mm, "
            f"max {result.max_mm:.4f} mm; rank {result.observability.rank}, "
            f"condition {result.observability.condition:.1f}; {result.message}"
        )
        print(f"written {args.out}")
    return 0 if result.success else 3
