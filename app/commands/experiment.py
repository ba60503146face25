"""`rvis experiment paper`: the paper's experiment on the simulated cell over many seeds;
`rvis experiment compensation`: compensated targets on the simulated cell (in
app/commands/compensate.py); `rvis experiment accuracy`: the rigid vs the compliance-aware model
against the noise floor; `rvis experiment shift`: a compressed shift of the in-line service on
the simulated line with warm-up and a knock (app/commands/experiment_shift.py, a campaign of
many app/commands/experiment_campaign.py); `rvis experiment maintenance`: a maintenance event
and its procedure end to end; the body's gauge studies (app/commands/gauge.py)."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from app.commands import add_command
from app.commands.args import int_at_least
from app.commands.compensate import run_compensation_experiment
from app.commands.experiment_campaign import run_knock_campaign
from app.commands.experiment_shift import run_shift_experiment, shift_options
from app.commands.gauge import STUDIES, add_options, run_study
from app.config import CellConfig, load_cell
from app.errors import InputError
from app.planning import add_plan_options, plan_overrides
from app.sim.accuracy import AccuracySettings, run_accuracy
from app.sim.accuracy import summary_text as accuracy_text
from app.sim.paper import run_experiment, summary_text
from fakes.truth import NO_KNOCK

EXPERIMENTS: dict[str, str] = {
    "paper": "the paper's experiment over many seeds (plan, identify, validate; fig. 11)",
    "paper-compare": "the reductions of paper runs side by side",
    "accuracy": "the rigid vs the compliance-aware model against the noise floor",
    "compensation": "nominal vs compensated pose error of the true robot",
    "shift": "a compressed shift of the in-line service with warm-up and a knock",
    "maintenance": "a maintenance event (sensor, axis, fixture) and its procedure, end to end",
    **STUDIES,
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
    shift_options(parsers["shift"])
    _maintenance_options(parsers["maintenance"])
    for name in STUDIES:
        add_options(parsers[name], name)
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


def _maintenance_options(g: argparse.ArgumentParser) -> None:
    g.add_argument("--event", choices=("sensor", "axis", "fixture"), required=True)
    g.add_argument("--axis", type=int_at_least(1), default=3, help="--event axis: which (3)")
    g.add_argument(
        "--sphere", default="", help="--event fixture: only this sphere replaced (default: all)"
    )
    g.add_argument(
        "--frame",
        action="store_true",
        help="--event fixture: the renewal moves the part frame against the robot's base",
    )
    g.add_argument("--seed", type=int_at_least(0), default=0, help="the cell's seed (0)")
    g.add_argument("--at-h", type=float, default=1.5, help="the event's hour of world time (1.5)")
    g.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    g.add_argument(
        "--rendered",
        action="store_true",
        help="every sweep rendered and measured through images (default: geometric; slow)",
    )
    g.add_argument(
        "--no-tracker",
        action="store_true",
        help="--event fixture: no tracker at hand (the spheres located by the robot)",
    )
    g.add_argument("--out", required=True, help="output folder (a new one)")


def run_maintenance_experiment(args: argparse.Namespace) -> int:
    """`rvis experiment maintenance` (app/sim/maintenance.py): DIR/maintenance.json."""
    from app.formats.jsontext import dumps_json
    from app.sim.maintenance import MaintenanceRun, run_maintenance, write_rows

    if args.axis > 6:
        raise InputError("the axis is 1..6", field="--axis")
    if not (math.isfinite(args.at_h) and args.at_h > 0):
        raise InputError("the event's hour must be > 0", field="--at-h")
    cfg = load_cell(args.cell)
    if args.sphere and (args.event != "fixture" or args.sphere not in cfg.spheres_part_mm):
        known = ", ".join(cfg.spheres_part_mm)
        raise InputError(
            f"one of the cell's spheres ({known}), with --event fixture",
            field="--sphere",
        )
    if args.frame and (args.event != "fixture" or args.sphere):
        raise InputError("with --event fixture and no --sphere", field="--frame")
    if args.no_tracker and args.event != "fixture":
        raise InputError("with --event fixture", field="--no-tracker")
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise InputError("the output folder is not empty", file=out)
    out.mkdir(parents=True, exist_ok=True)
    run = MaintenanceRun(
        args.event,
        args.seed,
        axis=args.axis,
        at_s=3600.0 * args.at_h,
        sphere=args.sphere,
        frame=args.frame,
        geometric=not args.rendered,
        no_tracker=args.no_tracker,
    )
    row = run_maintenance(cfg, out, run)
    path = write_rows(out, [row])
    keys = (
        "event", "event_window", "detected_after_windows", "suspect_from_window",
        "bodies_after_event_suspect", "procedure_passed", "procedure_robot_s",
        "commissioning_robot_s", "validation_before_mm", "validation_after_mm",
        "truth_before_mm", "truth_unchanged_mm", "truth_after_mm", "truth_line_after_mm",
        "truth_line_unchanged_mm",
    )  # fmt: skip
    print(dumps_json({k: row[k] for k in keys}, indent=2))
    print(f"written {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    for key in ("seeds", "validation", "views_per_sphere"):
        value = getattr(args, key, None)
        if value is not None and value < 1:
            raise InputError(f"must be >= 1, got {value}", field=f"--{key.replace('_', '-')}")
    if args.name == "compensation":
        return run_compensation_experiment(args)
    if args.name == "shift":
        if args.seeds is not None or args.knock == "all" or len(args.knock_at_h) > 1:
            if args.knock == NO_KNOCK:
                raise InputError(
                    "a campaign runs each shift without its knock too: --knock none is one"
                    " shift (no --seeds, one --knock-at-h)",
                    field="--knock",
                )
            return run_knock_campaign(args)
        return run_shift_experiment(args)
    if args.name == "paper-compare":
        return run_paper_compare(args.runs)
    if args.name == "maintenance":
        return run_maintenance_experiment(args)
    if args.name in STUDIES:
        return run_study(args)
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
