"""`rvis experiment paper`: the paper's experiment on the simulated cell over many seeds;
`rvis experiment compensation`: compensated targets on the simulated cell (in
app/commands/compensate.py); `rvis experiment accuracy`: the rigid vs the compliance-aware model
against the noise floor; `rvis experiment shift`: a compressed shift of the in-line service on
the simulated line with warm-up and a knock (app/sim/shift.py)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

from app.commands import add_command
from app.commands.args import int_at_least
from app.commands.compensate import run_compensation_experiment
from app.config import CellConfig, load_cell
from app.errors import InputError
from app.planning import add_plan_options, plan_overrides
from app.sim.accuracy import AccuracySettings, run_accuracy
from app.sim.accuracy import summary_text as accuracy_text
from app.sim.paper import run_experiment, summary_text

if TYPE_CHECKING:
    from app.sim.shift import ShiftSettings


EXPERIMENTS: dict[str, str] = {
    "paper": "the paper's experiment over many seeds (plan, identify, validate; fig. 11)",
    "paper-compare": "the reductions of paper runs side by side",
    "accuracy": "the rigid vs the compliance-aware model against the noise floor",
    "compensation": "nominal vs compensated pose error of the true robot",
    "shift": "a compressed shift of the in-line service with warm-up and a knock",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "experiment")
    names = p.add_subparsers(dest="name", metavar="NAME", required=True, parser_class=type(p))
    parsers = {n: names.add_parser(n, help=h, description=h) for n, h in EXPERIMENTS.items()}
    for name, default in (("paper", 20), ("accuracy", 10), ("compensation", 5), ("shift", 1)):
        e = parsers[name]
        e.add_argument("--seeds", type=int, help=f"number of seeds ({default})")
        e.add_argument("--first-seed", type=int, default=0, help="first seed (0)")
        e.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
        e.add_argument("--out", help="output folder (default runs/<experiment>-<time>)")
        if name != "shift":
            e.add_argument(
                "--validation", type=int, default=100, help="validation positions / poses (100)"
            )
    _paper_options(parsers["paper"])
    parsers["paper-compare"].add_argument(
        "--runs",
        nargs="+",
        metavar="[NAME=]DIR",
        required=True,
        help="output folders of paper runs, the first is the reference",
    )
    parsers["accuracy"].add_argument(
        "--views-per-sphere", type=int, default=10, help="random calibration views per sphere (10)"
    )
    _shift_options(parsers["shift"])
    for e in parsers.values():
        e.set_defaults(func=run)


def _paper_options(p: argparse.ArgumentParser) -> None:
    add_plan_options(p)
    p.add_argument(
        "--criteria-grid-step",
        type=float,
        help="grid [deg] for ranking O1..O5 as criteria (default: the plan's grid)",
    )
    p.add_argument(
        "--compliant",
        action="store_true",
        help="also identify and validate every run with the compliant model",
    )
    p.add_argument(
        "--no-criteria", action="store_true", help="skip ranking O1..O5 as selection criteria"
    )
    p.add_argument(
        "--plan-model",
        choices=("rigid", "compliant"),
        default="rigid",
        help="plan for the rigid model's 30 parameters (default) or the compliant model's"
        " (with the arm compliance, on its own pre-calibration)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="keep the seeds already in --out's seeds.json, run the others",
    )


def _shift_options(g: argparse.ArgumentParser) -> None:
    g.add_argument("--hours", type=float, default=8.0, help="sim hours (8)")
    g.add_argument("--knock-at-h", type=float, default=4.0, help="knock at hour (4)")
    g.add_argument(
        "--knock",
        choices=("sensor", "fixture", "joint", "all"),
        default="sensor",
        help="what the knock moves: the sensor mount (0.3 mm, 0.05 deg; default), the"
        " spheres' frame (0.5 mm, 0.03 deg) or the J2 zero (0.01 deg); all: each in turn"
        " (with --seeds: a campaign, shift-knocks.md)",
    )
    g.add_argument("--seed", type=int_at_least(0), default=0, help="seed of one shift (0)")
    g.add_argument(
        "--scale",
        type=float,
        help="pace the virtual time at this many sim seconds per real second, to watch it"
        " (default: as fast as the CPU; the outcome is the same)",
    )
    g.add_argument("--slots-per-window", type=int_at_least(1), help="default [line]")
    g.add_argument("--geometric", action="store_true", help="geometric measurements (default)")
    g.add_argument("--rendered", action="store_true", help="measure through images")
    g.add_argument(
        "--model",
        choices=("rigid", "compliant"),
        help="the model the service identifies (default [calibration] model)",
    )
    g.add_argument(
        "--estimator",
        choices=("batch", "sequential", "compare"),
        help="the service's estimator (default [service] estimator); compare: one shift each"
        " with batch, sequential and sequential with adaptive scheduling, and"
        " shift-estimators.md",
    )


def run(args: argparse.Namespace) -> int:
    for key in ("seeds", "validation", "views_per_sphere"):
        value = getattr(args, key, None)
        if value is not None and value < 1:
            raise InputError(f"must be >= 1, got {value}", field=f"--{key.replace('_', '-')}")
    if args.name == "compensation":
        return run_compensation_experiment(args)
    if args.name == "shift":
        if args.seeds is not None or args.knock == "all":
            return run_knock_campaign(args)
        return run_shift_experiment(args)
    if args.name == "paper-compare":
        return run_paper_compare(args.runs)
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/experiment-{time.strftime('%Y%m%d-%H%M%S')}")
    if args.name == "accuracy":
        return run_accuracy_command(args, cfg, out)
    overrides = plan_overrides(args)
    if args.resume and not args.out:
        raise InputError("--resume needs the --out folder of the run to resume", field="--resume")
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 20)))
    print(f"rvis experiment paper: {len(seeds)} seeds, writing to {out}/", flush=True)
    summary = run_experiment(
        cfg,
        seeds,
        out,
        n_validation=args.validation,
        criteria=not args.no_criteria,
        criteria_grid_step_deg=args.criteria_grid_step,
        log=lambda s: print(s, flush=True),
        compliant=args.compliant,
        plan_model=args.plan_model,
        resume=args.resume,
        **overrides,
    )
    print()
    print(summary_text(summary))
    print(f"\nwritten {out}/experiment.md, fig11.png, seeds.json in {summary.seconds:.0f} s")
    return 0


def run_paper_compare(specs: list[str]) -> int:
    """Print the runs' reductions side by side (app.sim.paper_compare) as a markdown table."""
    from app.formats.report import markdown_table
    from app.sim.paper_compare import HEADER, compare_rows, load_run

    if not specs:
        raise InputError("name at least one run folder", field="--runs")
    runs = {}
    for spec in specs:
        name, _, folder = spec.rpartition("=")
        runs[name or folder] = load_run(Path(folder))
    print(markdown_table(HEADER, compare_rows(runs)))
    return 0


def run_accuracy_command(args: argparse.Namespace, cfg: CellConfig, out: Path) -> int:
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 10)))
    settings = AccuracySettings(n_each=args.views_per_sphere, n_validation=args.validation)
    print(f"rvis experiment accuracy: {len(seeds)} seeds, writing to {out}/", flush=True)
    outcomes = run_accuracy(cfg, seeds, out, settings, log=lambda s: print(s, flush=True))
    print()
    print(accuracy_text(outcomes))
    print(f"\nwritten {out}/accuracy.md, accuracy-seeds.json")
    return 0


def run_shift_experiment(args: argparse.Namespace) -> int:
    from app.sim.line_run import WindowRecord
    from app.sim.shift import (
        run_shift,
        summary_lines,
        write_estimators,
        write_outputs,
    )

    settings = _shift_settings(args)
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/shift-{time.strftime('%Y%m%d-%H%M%S')}")
    if (out / "state").exists():
        raise InputError("the output folder already holds a shift's state", file=out / "state")

    def progress(r: WindowRecord) -> None:
        if r.window % 30 == 0:
            print(
                f"  window {r.window:4d}  t {r.t_h:5.2f} h  {r.temp_c:5.2f} C  true RMSE without"
                f" {r.rmse_commissioning_mm:.4f} mm, with the service {r.rmse_mm:.4f} mm"
                f"  v{r.version}",
                flush=True,
            )

    print(f"rvis experiment shift: {args.hours:g} h, knock at {args.knock_at_h:g} h -> {out}/")
    runs = {  # the name in the comparison -> (estimator, schedule)
        "batch": ("batch", "cycle"),
        "sequential": ("sequential", "cycle"),
        "sequential, adaptive": ("sequential", "adaptive"),
    }
    names = list(runs) if args.estimator == "compare" else [args.estimator]
    results = {}
    for name in names:
        estimator, schedule = runs[name] if args.estimator == "compare" else (name, None)
        s = dataclasses.replace(settings, estimator=estimator, schedule=schedule)
        sub = out if len(names) == 1 else out / str(name).replace(", ", "-")
        if len(names) > 1:
            print(f"estimator: {name}")
        results[str(name)] = result = run_shift(
            cfg, sub / "state", s, seed=args.seed, on_window=progress
        )
        command = _shift_command(args, result.scale, out) + f" --seed {args.seed}"
        paths = write_outputs(result, sub, command)
        print()
        print("\n".join(summary_lines(result)))
        print(f"\nwritten {', '.join(str(p) for p in paths)} in {result.real_s:.0f} s")
    if len(names) > 1:
        paths = write_estimators(results, out, command)
        print(f"written {', '.join(str(p) for p in paths)}")
    return 0


def _shift_settings(args: argparse.Namespace) -> ShiftSettings:
    from app.sim.shift import ShiftSettings

    if args.geometric and args.rendered:
        raise InputError("choose --geometric or --rendered", field="--rendered")
    try:
        return ShiftSettings(
            hours=args.hours,
            knock_at_h=args.knock_at_h,
            knock="sensor" if args.knock == "all" else args.knock,
            geometric=not args.rendered,
            scale=args.scale,
            slots_per_window=args.slots_per_window,
            model=args.model,
        )
    except ValueError as exc:
        raise InputError(str(exc), field="--hours/--knock-at-h/--scale") from exc


def _shift_command(args: argparse.Namespace, scale: float | None, out: Path) -> str:
    """The command line that reproduces a shift (for the outputs' headers)."""
    return (
        f"rvis experiment shift --hours {args.hours:g} --knock-at-h {args.knock_at_h:g}"
        f" --knock {args.knock}"
        + ("" if scale is None else f" --scale {scale:g}")
        + f" --out {out}"
        + (f" --slots-per-window {args.slots_per_window}" if args.slots_per_window else "")
        + (" --rendered" if args.rendered else "")
        + (f" --estimator {args.estimator}" if args.estimator else "")
        + (f" --model {args.model}" if args.model else "")
    )


def run_knock_campaign(args: argparse.Namespace) -> int:
    """`--seeds N` (from `--first-seed`) and/or `--knock all`: the shift for every seed and
    knock kind, each in `out/<kind>/seed-<n>/`, then `shift-knocks.md/.json/.png` (app.sim.knocks,
    rewritten after every run so that a campaign stopped half-way keeps what it measured)."""
    from app.sim.knocks import write_campaign
    from app.sim.shift import ShiftResult, run_shift, summary_lines, write_outputs

    if args.estimator == "compare":
        raise InputError("a campaign runs one estimator", field="--estimator")
    base = dataclasses.replace(_shift_settings(args), estimator=args.estimator)
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/knocks-{time.strftime('%Y%m%d-%H%M%S')}")
    kinds = ["sensor", "fixture", "joint"] if args.knock == "all" else [args.knock]
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 1)))
    for kind in kinds:
        if any((out / kind / f"seed-{n}" / "state").exists() for n in seeds):
            raise InputError("the output folder already holds a campaign's state", file=out)
    print(f"rvis experiment shift: {len(kinds)} knock kinds x {len(seeds)} seeds -> {out}/")
    results: dict[str, list[ShiftResult]] = {k: [] for k in kinds}
    command = ""
    for kind in kinds:
        for seed in seeds:
            sub = out / kind / f"seed-{seed}"
            result = run_shift(cfg, sub / "state", dataclasses.replace(base, knock=kind), seed=seed)
            command = _shift_command(args, result.scale, out) + (
                f" --seeds {len(seeds)} --first-seed {args.first_seed}"
            )
            write_outputs(result, sub, command + f" (seed {seed})")
            results[kind].append(result)
            print(f"{kind} seed {seed}: " + "; ".join(summary_lines(result)[:3]), flush=True)
            write_campaign({k: v for k, v in results.items() if v}, out, command)
    paths = write_campaign(results, out, command)
    print(f"written {', '.join(str(p) for p in paths)}")
    return 0
