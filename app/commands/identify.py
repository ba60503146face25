"""`rvis identify`: identify the 30 parameters from a measurements and a targets CSV.

The result is written only when it passes the quality gates of the cell's [calibration]
section (calib.gates); otherwise the command exits 3 with the reason on one line and leaves
`--out` as it was (`--keep-failed PATH` writes the failed result elsewhere for diagnosis)."""

from __future__ import annotations

import argparse
import sys

from app.commands import add_command

LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "identify")
    p.add_argument("--targets", required=True, help="targets CSV (tracker centres, part frame)")
    p.add_argument("--measurements", required=True, help="measurements CSV")
    p.add_argument("--out", required=True, help="parameters JSON to write")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--loss", choices=LOSSES, help="robust loss (default: [calibration] loss)")
    p.add_argument(
        "--add-param",
        action="append",
        default=[],
        metavar="NAME",
        help="identify an extra model parameter too (e.g. d1: the base's z absorbs it, so the "
        "command names the parameters that move together)",
    )
    p.add_argument("--keep-failed", metavar="PATH", help="write a failed result here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from app.config import load_cell
    from app.errors import InputError
    from app.formats.csvfiles import as_input_error, load_dataset_lines
    from app.formats.files import check_output, dumps_json, write_json
    from app.formats.params import to_json
    from app.formats.report import parameter_table
    from app.meta import provenance
    from calib.gates import check_identification
    from calib.identify import identify

    check_output(args.out)
    if args.keep_failed:
        check_output(args.keep_failed)
    cfg = load_cell(args.cell)
    model = cfg.identification_model()
    for name in args.add_param:
        if name not in model.names:
            raise InputError(f"unknown model parameter '{name}'", field="--add-param")
    loss = args.loss or cfg.calibration.loss
    data, data_lines = load_dataset_lines(args.measurements, args.targets, cfg.limits)
    default = tuple(model.default_active(data.temp_c))
    already = [n for n in args.add_param if n in default]
    if already:
        raise InputError(f"'{already[0]}' is identified already", field="--add-param")
    active = (*default, *args.add_param)
    result = as_input_error(
        args.measurements, lambda: identify(model, data, active=active, loss=loss)
    )
    report = check_identification(result, model.nominal_x(), cfg.calibration.gates())
    doc = to_json(model, result, report, provenance())
    if args.json:
        keys = ("residuals", "rank", "condition", "success", "converged", "gates")
        print(dumps_json({k: doc[k] for k in keys}))
    else:
        print(parameter_table(model, result))
        print(
            f"\n{len(data)} measurements, residual RMS {result.rms_mm:.4f} mm, "
            f"max {result.max_mm:.4f} mm; rank {result.observability.rank}, "
            f"condition {result.observability.condition:.1f}"
        )
    if not report.passed:
        worst = int(np.argmax(np.linalg.norm(result.residuals_mm, axis=1)))
        line = data_lines[worst] if worst < len(data_lines) else None
        if args.keep_failed:
            write_json(args.keep_failed, doc)
        kept = f" (failed result in {args.keep_failed})" if args.keep_failed else ""
        print(
            f"rvis identify: calibration rejected: {report.reason}; largest residual "
            f"{result.max_mm:.3f} mm at {args.measurements}:{line}; {args.out} not written{kept}",
            file=sys.stderr,
        )
        return 3
    write_json(args.out, doc)
    if not args.json:
        print(f"quality gates passed; written {args.out}")
    return 0
