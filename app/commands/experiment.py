"""`rvis experiment paper`: the paper's experiment on the simulated cell over many seeds;
`rvis experiment compensation`: compensated targets on the simulated cell (in
app/commands/compensate.py); `rvis experiment accuracy`: the rigid vs the compliance-aware model
against the noise floor; `rvis experiment shift`: a compressed shift of the in-line service on
the simulated line with warm-up and a knock (app/sim/shift.py)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.commands import add_command
from app.commands.args import int_at_least
from app.commands.compensate import run_compensation_experiment
from app.commands.gauge import STUDIES, add_options, run_study
from app.config import CellConfig, load_cell
from app.errors import InputError
from app.planning import add_plan_options, plan_overrides
from app.sim.accuracy import AccuracySettings, run_accuracy
from app.sim.accuracy import summary_text as accuracy_text
from app.sim.paper import run_experiment, summary_text
from fakes.truth import KNOCK_KINDS as KNOCKS
from fakes.truth import NO_KNOCK

if TYPE_CHECKING:
    from app.sim.shift import ShiftResult, ShiftSettings


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
    _shift_options(parsers["shift"])
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


DEFAULT_HOURS = 8.0  # `--hours` when neither it nor --after-h is given


def hours_list(text: str) -> list[float]:
    """`--knock-at-h`: one hour or a comma list of distinct hours, each a finite number > 0
    (that each lies inside its shift is checked with --hours, `_knock_hours`)."""
    hours: list[float] = []
    for part in text.split(","):
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{part.strip()}' is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"each hour must be > 0, got {part.strip()}")
        if value in hours:
            raise argparse.ArgumentTypeError(f"{part.strip()} is given twice")
        hours.append(value)
    return hours


def _knock_hours(args: argparse.Namespace) -> list[tuple[float, float]]:
    """(knock hour, shift hours) per `--knock-at-h` value: the shift runs to `--hours`, or to
    the knock + `--after-h` (rounded to the microhour, so that its reproduce command gives it)."""
    if args.after_h is not None and args.hours is not None:
        raise InputError("give --hours or --after-h, not both", field="--after-h")
    for name, value in (("--hours", args.hours), ("--after-h", args.after_h)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"must be > 0, got {value:g}", field=name)
    out = []
    for knock_h in args.knock_at_h:
        if args.after_h is not None:
            out.append((knock_h, round(knock_h + args.after_h, 6)))
            continue
        hours = DEFAULT_HOURS if args.hours is None else args.hours
        if not knock_h < hours:
            raise InputError(
                f"each hour must be < --hours ({hours:g}), got {knock_h:g}", field="--knock-at-h"
            )
        out.append((knock_h, hours))
    return out


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


def _shift_options(g: argparse.ArgumentParser) -> None:
    g.add_argument(
        "--hours",
        type=float,
        help=f"sim hours of a shift ({DEFAULT_HOURS:g}; not with --after-h)",
    )
    g.add_argument(
        "--knock-at-h",
        type=hours_list,
        default=[4.0],
        metavar="H[,H...]",
        help="knock at hour (4); a comma list (0.5,0.75,1.5): a campaign with a row per knock"
        " kind and hour, each hour > 0 and < the shift's hours",
    )
    g.add_argument(
        "--after-h",
        type=float,
        help="each shift runs to its knock's hour + this many hours (instead of --hours)",
    )
    g.add_argument(
        "--jobs",
        type=int_at_least(1),
        default=1,
        help="a campaign's shifts in this many worker processes (1; the same results)",
    )
    g.add_argument(
        "--knock",
        choices=(*KNOCKS, "all", NO_KNOCK),
        default="sensor",
        help="what the knock moves: the sensor mount (0.3 mm, 0.05 deg; default), the"
        " spheres' frame (0.5 mm, 0.03 deg), an axis's zero (J1..J6, joint = J2: 0.01 deg),"
        " one sphere alone (sphere: 0.5 mm); all: sensor, fixture and joint in turn (with"
        " --seeds: a campaign, shift-knocks.md); none: a shift without a knock (one shift)",
    )
    g.add_argument(
        "--knock-at-window",
        type=int_at_least(1),
        metavar="N",
        help="knock in the N-th window instead of at --knock-at-h (one shift)",
    )
    g.add_argument(
        "--before-knock",
        choices=("none", "restart", "rollback"),
        default="none",
        help="three windows before the knock: the service restarted on its state directory,"
        " or the engineer's rollback to the version before the one in force and the hold"
        " lifted (after the first in-line recalibration); none (default) (one shift)",
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
        help="the model the service identifies (default [service] model)",
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


def run_shift_experiment(args: argparse.Namespace) -> int:
    from app.sim.line_run import WindowRecord
    from app.sim.shift import run_shift
    from app.sim.shift_report import summary_lines, write_estimators, write_outputs

    cfg = load_cell(args.cell)
    if args.knock_at_window is not None:  # the N-th window opens at (N - 1) periods
        args.knock_at_h = [(args.knock_at_window - 1) * cfg.simline.period_s / 3600.0]
    if args.knock == NO_KNOCK:
        if args.after_h is not None or args.knock_at_window is not None:
            raise InputError("--knock none: no knock to time; give --hours", field="--knock")
        args.knock_at_h = [0.0]
    ((knock_h, hours),) = _knock_hours(args)
    settings = _shift_settings(args, knock_h, hours)
    if settings.before_knock != "none":
        from app.sim.shift import event_window

        try:
            event_window(cfg, settings)
        except ValueError as exc:
            raise InputError(str(exc), field="--before-knock") from exc
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

    knock = f"knock at {knock_h:g} h" if settings.knocked else "no knock"
    print(f"rvis experiment shift: {hours:g} h, {knock} -> {out}/")
    runs = {  # the name in the comparison -> (estimator, schedule)
        "batch": ("batch", "cycle"),
        "sequential": ("sequential", "cycle"),
        "sequential, adaptive": ("sequential", "adaptive"),
    }
    names = list(runs) if args.estimator == "compare" else [args.estimator]
    results = {}
    when = f"--hours {hours:g} --knock-at-h {knock_h:g}"
    for name in names:
        estimator, schedule = runs[name] if args.estimator == "compare" else (name, None)
        s = dataclasses.replace(settings, estimator=estimator, schedule=schedule)
        sub = out if len(names) == 1 else out / str(name).replace(", ", "-")
        if len(names) > 1:
            print(f"estimator: {name}")
        results[str(name)] = result = run_shift(
            cfg, sub / "state", s, seed=args.seed, on_window=progress
        )
        command = _shift_command(args, result.scale, out, when) + f" --seed {args.seed}"
        paths = write_outputs(result, sub, command)
        print()
        print("\n".join(summary_lines(result)))
        print(f"\nwritten {', '.join(str(p) for p in paths)} in {result.real_s:.0f} s")
    if len(names) > 1:
        paths = write_estimators(results, out, command)
        print(f"written {', '.join(str(p) for p in paths)}")
    return 0


def _shift_settings(args: argparse.Namespace, knock_h: float, hours: float) -> ShiftSettings:
    from app.sim.shift import ShiftSettings

    if args.geometric and args.rendered:
        raise InputError("choose --geometric or --rendered", field="--rendered")
    try:
        return ShiftSettings(
            hours=hours,
            knock_at_h=knock_h,
            knock="sensor" if args.knock == "all" else args.knock,
            geometric=not args.rendered,
            scale=args.scale,
            slots_per_window=args.slots_per_window,
            model=args.model,
            estimator=None if args.estimator in (None, "compare") else args.estimator,
            before_knock=getattr(args, "before_knock", "none"),
        )
    except ValueError as exc:
        raise InputError(str(exc), field="--hours/--knock-at-h/--scale") from exc


def _shift_command(args: argparse.Namespace, scale: float | None, out: Path, when: str) -> str:
    """The command line that reproduces a shift or a campaign (for the outputs' headers);
    `when`: its --hours / --knock-at-h / --after-h part."""
    return (
        f"rvis experiment shift {when}"
        f" --knock {args.knock}"
        + ("" if scale is None else f" --scale {scale:g}")
        + f" --out {out}"
        + (f" --slots-per-window {args.slots_per_window}" if args.slots_per_window else "")
        + (" --rendered" if args.rendered else "")
        + (f" --estimator {args.estimator}" if args.estimator else "")
        + (f" --model {args.model}" if args.model else "")
    )


def _campaign_when(args: argparse.Namespace, plan: list[tuple[float, float]]) -> str:
    """The campaign's --hours / --knock-at-h / --after-h, as given (one hour: as before)."""
    knocks = ",".join(f"{h:g}" for h, _ in plan)
    if args.after_h is not None:
        return f"--knock-at-h {knocks} --after-h {args.after_h:g}"
    return f"--hours {plan[0][1]:g} --knock-at-h {knocks}"


BASELINE = "without-knock"  # the counterfactual shifts' folder in a campaign


@dataclasses.dataclass(frozen=True)
class _CampaignShift:
    """One shift of a campaign: what a worker process needs to run it and write its outputs."""

    kind: str
    knock_h: float
    seed: int
    folder: Path
    settings: ShiftSettings
    header: str  # the command line in its shift.md
    reproduce: str  # the command that runs it alone


def _run_campaign_shift(cfg: CellConfig, task: _CampaignShift) -> ShiftResult:
    """Run one shift of a campaign and write its shift.md/.json/.png (in a worker process
    with --jobs N: a module-level function, its arguments and result picklable)."""
    from app.sim.shift import run_shift
    from app.sim.shift_report import write_outputs

    result = run_shift(cfg, task.folder / "state", task.settings, seed=task.seed)
    write_outputs(result, task.folder, task.header)
    return result


def run_knock_campaign(args: argparse.Namespace) -> int:
    """`--seeds N` (from `--first-seed`), `--knock all` and/or several `--knock-at-h` hours:
    the shift for every knock kind, hour and seed, each in `out/<kind>/seed-<n>/` (several
    hours: `out/<kind>/at-<h>h/seed-<n>/`), then `shift-knocks.md/.json/.png` (app.sim.knocks,
    rewritten after every run so that a campaign stopped half-way keeps what it measured).
    `--jobs N` runs the shifts in N worker processes: each shift is deterministic (virtual
    time) and independent, and the campaign is assembled in the same order, so the outputs are
    those of --jobs 1 apart from the wall times."""
    from app.sim.knocks import write_campaign
    from app.sim.shift import evaluate
    from app.sim.shift_report import summary_lines, write_outputs

    if args.estimator == "compare":
        raise InputError("a campaign runs one estimator", field="--estimator")
    if getattr(args, "before_knock", "none") != "none":
        raise InputError(
            "one shift only (a campaign with one: bench/estimator.py --before-knock)",
            field="--before-knock",
        )
    plan = _knock_hours(args)
    bases = {h: _shift_settings(args, h, hours) for h, hours in plan}
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/knocks-{time.strftime('%Y%m%d-%H%M%S')}")
    kinds = ["sensor", "fixture", "joint"] if args.knock == "all" else [args.knock]
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 1)))
    several = len(plan) > 1
    command = _shift_command(args, args.scale, out, _campaign_when(args, plan)) + (
        f" --seeds {len(seeds)} --first-seed {args.first_seed}"
    )
    tasks = []
    for kind in kinds:
        for knock_h, hours in plan:
            for seed in seeds:
                folder = out / kind / (f"at-{knock_h:g}h" if several else "") / f"seed-{seed}"
                if (folder / "state").exists():
                    raise InputError("the output folder already holds a campaign's state", file=out)
                reproduce = _reproduce(args, kind, knock_h, hours, seed)
                tasks.append(
                    _CampaignShift(
                        kind,
                        knock_h,
                        seed,
                        folder,
                        dataclasses.replace(bases[knock_h], knock=kind),
                        reproduce if several else command + f" (seed {seed})",
                        reproduce,
                    )
                )
    # the counterfactual: each seed's longest shift without the knock (which windows the knock
    # caused: above the ratio of the pre-knock level and of this run's error in the window)
    longest_h, longest = max(plan, key=lambda p: p[1])
    baselines = [
        _CampaignShift(
            BASELINE,
            longest_h,
            seed,
            out / BASELINE / f"seed-{seed}",
            dataclasses.replace(bases[longest_h], knock_mm=0.0, knock_deg=0.0),
            f"{command} (seed {seed}, the same shift without its knock)",
            "",
        )
        for seed in seeds
    ]
    what = f"{len(kinds)} knock kinds x {len(seeds)} seeds"
    if several:
        what += f" x {len(plan)} knock hours"
    what += f", and {len(seeds)} shifts of {longest:g} h without a knock"
    jobs = min(args.jobs, len(tasks) + len(baselines))
    print(f"rvis experiment shift: {what} -> {out}/" + (f" ({jobs} jobs)" if jobs > 1 else ""))
    done: dict[int, ShiftResult] = {}
    base_of: dict[int, list[float]] = {}

    def finished(i: int, result: ShiftResult) -> None:
        if i >= len(tasks):  # a counterfactual
            base_of[result.seed] = [r.rmse_mm for r in result.records]
            print(f"seed {result.seed} without the knock: done", flush=True)
            return
        done[i] = result
        t = tasks[i]
        at = f" at {t.knock_h:g} h" if several else ""
        print(f"{t.kind}{at} seed {t.seed}: " + "; ".join(summary_lines(result)[:3]), flush=True)
        write_campaign(_by_kind(tasks, done), out, command, commands=_commands(tasks, done))

    everything = tasks + baselines
    if jobs == 1:
        for i, task in enumerate(everything):
            finished(i, _run_campaign_shift(cfg, task))
    else:
        _run_in_workers(cfg, everything, jobs, finished, getattr(args, "log_level", "off"))
    for i, result in done.items():  # scored again against the counterfactual
        result.baseline_mm = base_of.get(result.seed)
        evaluate(result)
        write_outputs(result, tasks[i].folder, tasks[i].header)
    paths = write_campaign(_by_kind(tasks, done), out, command, commands=_commands(tasks, done))
    print(f"written {', '.join(str(p) for p in paths)}")
    return 0


def _reproduce(args: argparse.Namespace, kind: str, knock_h: float, hours: float, seed: int) -> str:
    """The command that runs one shift of a campaign alone."""
    alone = argparse.Namespace(**{**vars(args), "knock": kind})
    out = Path("runs") / f"{kind}-{knock_h:g}h-seed-{seed}"
    when = f"--hours {hours:g} --knock-at-h {knock_h:g}"
    return _shift_command(alone, args.scale, out, when) + f" --seed {seed}"


def _by_kind(tasks: list[_CampaignShift], done: dict[int, ShiftResult]) -> dict[str, list[Any]]:
    """The finished shifts per knock kind, in the campaign's order (kind, hour, seed)."""
    out: dict[str, list[Any]] = {}
    for i, task in enumerate(tasks):
        if i in done:
            out.setdefault(task.kind, []).append(done[i])
    return out


def _commands(tasks: list[_CampaignShift], done: dict[int, ShiftResult]) -> list[str]:
    return [t.reproduce for i, t in enumerate(tasks) if i in done]


def _run_in_workers(
    cfg: CellConfig,
    tasks: list[_CampaignShift],
    jobs: int,
    finished: Callable[[int, ShiftResult], None],
    log_level: str = "off",
) -> None:
    """The shifts in `jobs` fresh worker processes (spawned: nothing of this process's state,
    threads or caches is inherited; their logging as the command's, `log_level`),
    `finished(i, result)` as each ends."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

    from app.commands.logs import configure

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        max_workers=jobs, mp_context=context, initializer=configure, initargs=(log_level,)
    ) as pool:
        pending: dict[Future[ShiftResult], int] = {
            pool.submit(_run_campaign_shift, cfg, task): i for i, task in enumerate(tasks)
        }
        try:
            while pending:
                ready, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(ready, key=lambda f: pending[f]):
                    finished(pending.pop(future), future.result())
        except BaseException:
            for future in pending:
                future.cancel()
            raise
