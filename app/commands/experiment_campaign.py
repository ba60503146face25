"""`rvis experiment shift` as a campaign (`--seeds`, `--knock all` or several `--knock-at-h`):
every knock kind, hour and seed, each shift beside its counterfactual without the knock, in
worker processes (`--jobs`), and the campaign's tables (app/sim/shift_report.py)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.commands.experiment_shift import knock_hours, shift_command, shift_settings
from app.config import CellConfig, load_cell
from app.errors import InputError

if TYPE_CHECKING:
    from app.sim.shift_result import ShiftResult, ShiftSettings


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
    from app.sim.shift_report import summary_lines, write_outputs
    from app.sim.shift_score import evaluate

    if args.estimator == "compare":
        raise InputError("a campaign runs one estimator", field="--estimator")
    if getattr(args, "before_knock", "none") != "none":
        raise InputError(
            "one shift only (a campaign with one: bench/estimator.py --before-knock)",
            field="--before-knock",
        )
    plan = knock_hours(args)
    bases = {h: shift_settings(args, h, hours) for h, hours in plan}
    cfg = load_cell(args.cell)
    out = Path(args.out or f"runs/knocks-{time.strftime('%Y%m%d-%H%M%S')}")
    kinds = ["sensor", "fixture", "joint"] if args.knock == "all" else [args.knock]
    seeds = list(range(args.first_seed, args.first_seed + (args.seeds or 1)))
    several = len(plan) > 1
    command = shift_command(args, args.scale, out, _campaign_when(args, plan)) + (
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
    return shift_command(alone, args.scale, out, when) + f" --seed {seed}"


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
