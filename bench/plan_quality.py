"""The plan's quality over seeds, for the code it runs on (issue 31 item 1): per seed of the
simulated cell, as `rvis experiment paper` runs a seed (app/sim/paper.py, without ranking the
criteria): the pre-calibration from 6 random configurations per Table 1 sphere, the plan on
its parameters (default settings: PSO placement, DETMAX on the 5 deg grid), the calibration
with the planned configurations at the planned positions, both validated at the same 100
positions.

Per seed: O1 of the plan (its own Jacobian on the pre-calibrated parameters), O1 of the
planned calibration (at its identified parameters), the validation RMSE against the tracker and
against the truth, the random pre-calibration's RMSE (the same for any planner: a check that
both runs saw the same cells), and the plan's CPU seconds (process + worker processes) and wall
seconds.

    # on this code, then on main's (a worktree at main) with the same script, then compare
    .venv/bin/python bench/plan_quality.py --seeds 10 --out /tmp/q_new.json
    .venv/bin/python bench/plan_quality.py --code ../main --seeds 10 --out /tmp/q_ref.json
    .venv/bin/python bench/plan_quality.py --compare /tmp/q_ref.json /tmp/q_new.json

`--code DIR` imports the application from DIR (default: this checkout; `--label` names it in
the output, default its commit). Extra planning options go to the plan as in rvis plan
(`--set patience=0`). `--plan-seed-offset K` plans with seed + K on the same cells: the spread
that the plan's own random stream (the swarm's particles, DETMAX's start) causes, the yardstick
for "within noise".
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_seed(
    seed: int, overrides: dict[str, Any], n_validation: int, plan_seed: int
) -> dict[str, Any]:
    from app.config import load_cell
    from app.planning import run_plan
    from app.sim.cell import collect, simulated_sets
    from app.sim.demo import truth_set
    from calib.identify import identify, residuals
    from calib.validation import rmse

    cfg = load_cell(None)
    sim = simulated_sets(cfg, seed, n_validation=n_validation)
    cell, model, rng, pre_data, val = sim.cell, sim.model, sim.rng, sim.calibration, sim.validation
    val_truth = truth_set(val, val.truth_c_sensor_mm, with_noise=False)
    loss = str(cfg.calibration["loss"])
    pre = identify(model, pre_data.measurements, loss=loss)
    t, c = time.perf_counter(), _cpu_seconds()
    plan = run_plan(cfg, model, pre.x, seed=plan_seed, **overrides)
    cpu, wall = _cpu_seconds() - c, time.perf_counter() - t
    n_each = cfg.calibration.configs_per_sphere
    planned = collect(cell, model, pre.x, plan.positions_part_mm(), n_each, rng,
                      q_by_target=plan.q_by_sphere())  # fmt: skip
    res = identify(model, planned.measurements, loss=loss)
    return {
        "seed": seed,
        "plan_seed": plan_seed,
        "plan_o1": plan.observability.indices["O1"],
        "calibration_o1": res.observability.indices["O1"],
        "rmse_mm": rmse(residuals(model, res.x, val.measurements)),
        "rmse_truth_mm": rmse(residuals(model, res.x, val_truth)),
        "random_rmse_mm": rmse(residuals(model, pre.x, val.measurements)),
        "plan_cpu_s": cpu,
        "plan_wall_s": wall,
        "positions_part_mm": {k: v.round(3).tolist() for k, v in plan.positions_part_mm().items()},
        "fitness_evaluations": {k: len(v) for k, v in plan.fitness_history.items()},
    }


def _commit(code: Path) -> str:
    out = subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"],
                         capture_output=True, text=True, check=False)  # fmt: skip
    dirty = subprocess.run(["git", "-C", str(code), "status", "--porcelain", "--", "calib", "app"],
                           capture_output=True, text=True, check=False).stdout.strip()  # fmt: skip
    return out.stdout.strip() + ("+changes" if dirty else "")


def measure(args: argparse.Namespace) -> None:
    code = Path(args.code).resolve()
    sys.path.insert(0, str(code))
    from app.threads import limit_blas_threads

    limit_blas_threads()
    overrides: dict[str, Any] = {}
    for item in args.set:
        key, value = item.split("=", 1)
        overrides[key] = float(value) if "." in value else int(value)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    out: dict[str, Any] = {"code": str(code), "commit": args.label or _commit(code),
                           "overrides": overrides, "plan_seed_offset": args.plan_seed_offset,
                           "load_1min": [], "seeds": []}  # fmt: skip
    for seed in seeds:
        out["load_1min"].append(os.getloadavg()[0])
        row = run_seed(seed, overrides, args.validation, seed + args.plan_seed_offset)
        out["seeds"].append(row)
        print(f"seed {seed}: plan O1 {row['plan_o1']:.4f}, RMSE {row['rmse_mm']:.4f} mm "
              f"(truth {row['rmse_truth_mm']:.4f}), plan {row['plan_cpu_s']:.1f} s CPU "
              f"{row['plan_wall_s']:.1f} s wall", flush=True)  # fmt: skip
        if args.out:
            Path(args.out).write_text(json.dumps(out, indent=1))


def _median(rows: list[dict[str, Any]], key: str) -> float:
    return float(statistics.median(r[key] for r in rows))


def compare(ref_path: str, new_path: str) -> None:
    ref, new = (json.loads(Path(p).read_text()) for p in (ref_path, new_path))
    by_seed = {r["seed"]: r for r in ref["seeds"]}
    pairs = [(by_seed[r["seed"]], r) for r in new["seeds"] if r["seed"] in by_seed]
    a, b = [p[0] for p in pairs], [p[1] for p in pairs]
    print(f"reference: {ref['commit']} {ref['overrides']} plan seed + "
          f"{ref.get('plan_seed_offset', 0)}; new: {new['commit']} {new['overrides']} plan seed + "
          f"{new.get('plan_seed_offset', 0)}")  # fmt: skip
    print(f"{len(pairs)} seeds: {', '.join(str(r['seed']) for r in b)}\n")
    print("| seed | plan O1 ref | plan O1 new | calib. O1 ref | calib. O1 new | RMSE ref [mm] "
          "| RMSE new [mm] | RMSE truth ref | RMSE truth new | random RMSE (both) "
          "| plan CPU ref [s] | plan CPU new [s] |")  # fmt: skip
    print("|" + "---|" * 12)
    for r, n in pairs:
        same = "" if abs(r["random_rmse_mm"] - n["random_rmse_mm"]) < 1e-12 else " (differs!)"
        print(f"| {n['seed']} | {r['plan_o1']:.4f} | {n['plan_o1']:.4f} "
              f"| {r['calibration_o1']:.4f} | {n['calibration_o1']:.4f} "
              f"| {r['rmse_mm']:.4f} | {n['rmse_mm']:.4f} "
              f"| {r['rmse_truth_mm']:.4f} | {n['rmse_truth_mm']:.4f} "
              f"| {n['random_rmse_mm']:.4f}{same} "
              f"| {r['plan_cpu_s']:.1f} | {n['plan_cpu_s']:.1f} |")  # fmt: skip
    print()
    print("| median over seeds | reference | new | new / reference |")
    print("|---|---|---|---|")
    rows = (
        ("plan_o1", "plan O1"),
        ("calibration_o1", "O1 of the planned calibration"),
        ("rmse_mm", "validation RMSE [mm]"),
        ("rmse_truth_mm", "RMSE vs truth [mm]"),
        ("plan_cpu_s", "plan CPU [s]"),
        ("plan_wall_s", "plan wall [s]"),
    )
    for key, label in rows:
        ma, mb = _median(a, key), _median(b, key)
        print(f"| {label} | {ma:.4f} | {mb:.4f} | {mb / ma:.3f} |")
    for key, label in (("plan_o1", "plan O1"), ("rmse_mm", "validation RMSE"),
                       ("rmse_truth_mm", "RMSE vs truth")):  # fmt: skip
        d = [n[key] / r[key] - 1.0 for r, n in pairs]
        better = sum(x > 0 for x in d) if key == "plan_o1" else sum(x < 0 for x in d)
        sd = statistics.stdev(d) if len(d) > 1 else float("nan")
        print(f"\n{label}, new / ref - 1 per seed: median {100 * statistics.median(d):+.2f} %, "
              f"mean {100 * statistics.fmean(d):+.2f} % (sd {100 * sd:.2f} %, standard error "
              f"{100 * sd / len(d) ** 0.5:.2f} %), new better on {better}/{len(d)}")  # fmt: skip
    spread = [n["rmse_mm"] / n["random_rmse_mm"] for n in b]
    print(f"\n(for scale: planned / random RMSE per seed spans {min(spread):.3f} .. "
          f"{max(spread):.3f})")  # fmt: skip
    load = ref.get("load_1min", []) + new.get("load_1min", [])
    if load:
        print(f"load average (1 min) during the runs: {min(load):.1f} .. {max(load):.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--code", default=str(ROOT), help="checkout whose app/ and calib/ run")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--validation", type=int, default=100)
    ap.add_argument("--plan-seed-offset", type=int, default=0,
                    help="plan with seed + K (the same cells): the spread of the plan's own "
                    "random stream (PSO, DETMAX's start)")  # fmt: skip
    ap.add_argument("--label", help="name of the code in the output (default: its commit)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="planning override, e.g. iterations=30")  # fmt: skip
    ap.add_argument("--out", help="JSON of the per-seed figures")
    ap.add_argument("--compare", nargs=2, metavar=("REF", "NEW"), help="table of two runs")
    args = ap.parse_args()
    if args.compare:
        compare(*args.compare)
    else:
        measure(args)


if __name__ == "__main__":
    main()
