"""`rvis validate`: Euclidean errors of a parameter set at validation positions."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

import numpy as np

from app.commands import add_command
from app.formats.csvfiles import load_dataset
from app.formats.files import ERROR_COLUMNS, check_output, write_csv
from app.formats.params import from_json
from app.formats.report import STATS_HEADER, stats_rows, text_table
from calib.identify import residuals
from calib.validation import ErrorStats


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "validate")
    p.add_argument("--params", required=True, help="parameters JSON (from rvis identify)")
    p.add_argument("--targets", required=True, help="validation targets CSV")
    p.add_argument("--measurements", required=True, help="validation measurements CSV")
    p.add_argument("--out", help="errors CSV to write")
    p.add_argument(
        "--allow-failed", action="store_true", help="read a parameters file that failed its gates"
    )
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.out:
        check_output(args.out)
    model, x = from_json(args.params, allow_failed=args.allow_failed)
    data = load_dataset(args.measurements, args.targets, model.limits)
    e_id = residuals(model, x, data)
    e_nom = residuals(model, model.nominal_x(), data)
    stats = {"nominal": ErrorStats.of(e_nom), "identified": ErrorStats.of(e_id)}
    if args.out:
        p = model.points_part(x, data.q_deg, data.c_sensor_mm)
        d = np.linalg.norm(e_id, axis=1)
        rows = [
            [t, *map(float, p[i]), *map(float, e_id[i]), float(d[i])]
            for i, t in enumerate(data.targets)
        ]
        write_csv(args.out, ERROR_COLUMNS, rows)
    if args.json:
        print(json.dumps({k: asdict(v) for k, v in stats.items()}))
    else:
        print(text_table(STATS_HEADER, stats_rows(stats)) + "\n(all values in mm)")
    return 0
