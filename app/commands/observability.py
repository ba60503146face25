"""`rvis observability`: rank, condition and O1..O5 of a measurement set."""

from __future__ import annotations

import argparse
import json

from app.commands import add_command
from app.config import load_cell
from app.formats.csvfiles import as_input_error
from app.formats.files import read_measurements
from app.formats.params import from_json
from calib.model import PAPER_30
from calib.observability import INDEX_NAMES, null_space_groups, observability


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "observability")
    p.add_argument("--measurements", required=True, help="measurements CSV")
    p.add_argument("--params", help="parameters JSON to evaluate at (default: nominal)")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument(
        "--allow-failed", action="store_true", help="read a parameters file that failed its gates"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.params:
        model, x = from_json(args.params, allow_failed=args.allow_failed)
    else:
        model = load_cell(args.cell).model()
        x = model.nominal_x()
    rows = read_measurements(args.measurements, model.limits)
    J = model.point_jacobian(x, rows.q_deg, rows.c_sensor_mm, PAPER_30).reshape(-1, len(PAPER_30))
    obs = as_input_error(args.measurements, lambda: observability(J, len(rows.targets)))
    groups = null_space_groups(J, PAPER_30) if obs.rank < len(PAPER_30) else []
    if args.json:
        print(
            json.dumps(
                {
                    "rank": obs.rank,
                    "n_parameters": obs.n_params,
                    "n_measurements": obs.n_configs,
                    "condition": obs.condition,
                    "indices": obs.indices,
                    "not_identifiable": groups,
                }
            )
        )
    else:
        print(
            f"measurements {obs.n_configs}, parameters {obs.n_params}, rank {obs.rank}, "
            f"condition {obs.condition:.4g} (column-scaled)"
        )
        for name in INDEX_NAMES:
            print(f"  {name} = {obs.indices[name]:.6g}")
        for g in groups:
            print("  not identifiable together: " + ", ".join(g))
    return 0
