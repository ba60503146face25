"""`rvis experiment shift`, one shift (app/sim/shift.py): its options, its knock's hours and the
command line that reproduces it; a campaign of many (`--seeds`, several kinds or hours) is
app/commands/experiment_campaign.py."""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

from app.commands.args import int_at_least
from app.config import load_cell
from app.errors import InputError
from fakes.truth import KNOCK_KINDS as KNOCKS
from fakes.truth import NO_KNOCK

if TYPE_CHECKING:
    from app.sim.shift_result import ShiftSettings


DEFAULT_HOURS = 8.0  # `--hours` when neither it nor --after-h is given


def hours_list(text: str) -> list[float]:
    """`--knock-at-h`: one hour or a comma list of distinct hours, each a finite number > 0
    (that each lies inside its shift is checked with --hours, `knock_hours`)."""
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


def knock_hours(args: argparse.Namespace) -> list[tuple[float, float]]:
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


def shift_options(g: argparse.ArgumentParser) -> None:
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


def run_shift_experiment(args: argparse.Namespace) -> int:
    from app.sim.line_records import WindowRecord
    from app.sim.shift import run_shift
    from app.sim.shift_report import summary_lines, write_estimators, write_outputs

    cfg = load_cell(args.cell)
    if args.knock_at_window is not None:  # the N-th window opens at (N - 1) periods
        args.knock_at_h = [(args.knock_at_window - 1) * cfg.simline.period_s / 3600.0]
    if args.knock == NO_KNOCK:
        if args.after_h is not None or args.knock_at_window is not None:
            raise InputError("--knock none: no knock to time; give --hours", field="--knock")
        args.knock_at_h = [0.0]
    ((knock_h, hours),) = knock_hours(args)
    settings = shift_settings(args, knock_h, hours)
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
        command = shift_command(args, result.scale, out, when) + f" --seed {args.seed}"
        paths = write_outputs(result, sub, command)
        print()
        print("\n".join(summary_lines(result)))
        print(f"\nwritten {', '.join(str(p) for p in paths)} in {result.real_s:.0f} s")
    if len(names) > 1:
        paths = write_estimators(results, out, command)
        print(f"written {', '.join(str(p) for p in paths)}")
    return 0


def shift_settings(args: argparse.Namespace, knock_h: float, hours: float) -> ShiftSettings:
    from app.sim.shift_result import ShiftSettings

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


def shift_command(args: argparse.Namespace, scale: float | None, out: Path, when: str) -> str:
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
