"""`rvis demo`: the simulated cell end to end, no configuration file needed."""

from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import closing, nullcontext
from pathlib import Path

from app.commands import add_command
from app.commands.args import int_at_least
from app.config import CellConfig, load_cell
from app.errors import InputError
from app.formats.report import parameter_table
from app.planning import ProgressLine
from app.sim.cell import (
    GeometricMeasurement,
    RenderedMeasurement,
    calibrated_sensor_model,
    true_sensor_model,
)
from app.sim.demo import run_demo, summary_text
from fakes.render_sensor import default_true_sensor


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "demo")
    p.add_argument("--seed", type=int_at_least(0), help="seed (default: [simulation] seed)")
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
    p.add_argument(
        "--geometric",
        action="store_true",
        help="fast geometric measurements (true centre plus noise) instead of "
        "rendered sweeps measured by the vision pipeline",
    )
    p.add_argument(
        "--sensor-model",
        choices=("calibrated", "truth"),
        default="calibrated",
        help="rendered path: measure with a sensor model calibrated from rendered chessboards "
        "and target sweeps (default, as on the line) or with the simulated truth",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=min(2, os.cpu_count() or 1),
        help="processes rendering sweeps (default: up to 2)",
    )
    p.add_argument(
        "--no-line",
        action="store_true",
        help="skip the line part (the in-line service on the simulated line with a knock)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_cell(args.cell)
    if args.seed is None:
        args.seed = cfg.simulation.seed
    out = Path(args.out or f"runs/demo-{time.strftime('%Y%m%d-%H%M%S')}")
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    measurement: GeometricMeasurement | RenderedMeasurement
    if args.geometric:
        measurement, how = GeometricMeasurement(), "geometric measurements"
    else:
        if args.sensor_model == "calibrated":
            sensor_model, info = calibrated_sensor_model(default_true_sensor(), args.seed)
            how = (
                "sensor calibrated from 12 rendered chessboards and 4 target sweeps (focal "
                f"length off by {info['fx_error_px']:+.2f} px, principal point by "
                f"({info['cx_error_px']:+.2f}, {info['cy_error_px']:+.2f}) px); "
            )
        else:
            sensor_model, how = true_sensor_model(default_true_sensor()), "true sensor model; "
        measurement = RenderedMeasurement(
            sensor_model=sensor_model,
            sensor_frame_exact=args.sensor_model == "truth",
            workers=args.workers,
            progress=lambda line: print(line, flush=True),
        )
        how += f"rendered sweeps on {args.workers} worker(s)"
    print(f"rvis demo: simulated cell, seed {args.seed}, {how}; running ...", flush=True)
    with closing(measurement) if isinstance(measurement, RenderedMeasurement) else nullcontext():
        demo = run_demo(
            cfg,
            args.seed,
            out,
            args.validation,
            None if args.placement == "none" else args.placement,
            progress=ProgressLine(sys.stderr),
            measurement=measurement,
        )
    print(parameter_table(cfg.model(), demo.result))
    print()
    print(summary_text(demo))
    print(
        f"\nReport written to {out}/ (report.md, report.json, params.json, "
        f"validation_errors.png, CSV files) in {demo.seconds:.1f} s"
    )
    if not args.no_line:
        line_part(cfg, out, args.seed)
    return 0


def line_part(cfg: CellConfig, out: Path, seed: int) -> None:
    """A few dozen windows of the in-line service on the simulated line with a knock
    (geometric, high time scale): line.png/.md/.json in the run folder, two lines in
    report.md."""
    from app.sim.shift import run_shift
    from app.sim.shift_report import summary_lines, write_outputs
    from app.sim.shift_result import DEMO_SHIFT

    print(
        "\nline part: the in-line service on the simulated line, a knock at"
        f" {DEMO_SHIFT.knock_at_h * 60:g} min ...",
        flush=True,
    )
    result = run_shift(cfg, out / "line-state", DEMO_SHIFT, seed=seed)
    write_outputs(result, out, "rvis demo", stem="line")
    lines = summary_lines(result)[:2]
    with (out / "report.md").open("a") as f:
        f.write("\n## In-line service (simulated line, line.md, line.png)\n\n")
        f.write("".join(f"- {line}\n" for line in lines))
    print("\n".join(lines))
    print(f"line part written to {out}/ (line.md, line.png, line.json) in {result.real_s:.0f} s")
