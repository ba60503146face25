"""Benchmark of measurement planning (issues 3 and 31). Prints medians of repeated runs.

1. DETMAX choosing 6 of 20k candidates (with 6 fixed configurations of another sphere):
   rank-3 determinant updates vs the straightforward full SVD per candidate, same run,
   same selection.
2. The full four-sphere plan with the default settings (swarm 50, up to 30 iterations, PSO
   fitness on the 30 deg grid, final configurations on the 5 deg grid, 2 processes), in this
   process; aim <= 10 s on a quiet 2-core machine.
3. `rvis plan` as its own process, this code against a reference checkout (`--reference DIR`,
   e.g. a worktree at main), in the same run: the runs alternate (the order rotates every
   repeat), medians of wall and CPU seconds (the process and its worker processes) and their
   ratio to the reference's; also this code with `--patience 0` (every PSO iteration, as the
   reference: the speed-ups that leave the plan as it was, which its O1 shows).
4. Coarse to fine: with a small swarm, the final O1 when the swarm's fitness uses the
   30 deg grid vs the full 5 deg grid (aim: within 2 %).
5. Closed-form IK throughput vs py-opw-kinematics (bench/ik.py), same poses, same run.

  .venv/bin/python bench/plan.py [--repeats N] [--reference DIR] [--skip-svd]
      [--skip-grid-check] [--skip-full] [--skip-cli] [--skip-detmax] [--skip-ik]

On a shared machine compare CPU seconds, and wall seconds only as ratios within one run.
"""

from __future__ import annotations

import os

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point, before numpy loads

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import load_cell
from app.planning import plan_settings, run_plan
from calib import detmax
from calib.candidates import ViewGrid
from calib.configurations import candidate_blocks


def timed(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def bench_detmax(skip_svd: bool, repeats: int) -> None:
    cfg = load_cell(None)
    model = cfg.model()
    x = model.nominal_x()
    settings, _ = plan_settings(cfg)
    _, J_all = candidate_blocks(model, x, cfg.spheres_part_mm["P2"], ViewGrid(5.0), settings)
    pick = np.random.default_rng(0).choice(len(J_all), 20_000, replace=False)
    J = J_all[pick]
    _, J1 = candidate_blocks(model, x, cfg.spheres_part_mm["P1"], ViewGrid(30.0), settings)
    fixed = J1[:: max(1, len(J1) // 6)][:6]

    def run(updates: str) -> detmax.Selection:
        return detmax.select(J, 6, np.random.default_rng(0), J_fixed=fixed, updates=updates)

    t_fast, fast = timed(lambda: run("rank3"), repeats)
    print(f"{'DETMAX, 20k candidates, rank-3 updates':52s} {t_fast:9.3f} s "
          f"({fast.sweeps} candidate sweeps)")  # fmt: skip
    if skip_svd:
        return
    t_slow, slow = timed(lambda: run("svd"), 1)
    same = np.array_equal(np.sort(fast.indices), np.sort(slow.indices))
    print(f"{'DETMAX, 20k candidates, SVD per candidate (ref.)':52s} {t_slow:9.3f} s "
          f"(single run; same selection: {same})")  # fmt: skip
    print(f"{'  rank-3 updates vs SVD per candidate':52s} {t_slow / t_fast:9.1f}x faster")


def timed_cpu(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """Median wall-clock and CPU seconds (this process and its finished children: the swarm's
    worker processes end with each plan) of repeated runs, and the last result."""
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        t, c = time.perf_counter(), os.times()
        out = fn()
        c2 = os.times()
        walls.append(time.perf_counter() - t)
        cpus.append(sum(c2[:4]) - sum(c[:4]))  # user + system, self + children
    return statistics.median(walls), statistics.median(cpus), out


def bench_full_plan(repeats: int) -> None:
    cfg = load_cell(None)
    model = cfg.model()
    x = model.nominal_x()
    t, cpu, plan = timed_cpu(lambda: run_plan(cfg, model, x), repeats)
    o, r = plan.observability.indices, plan.random_observability.indices
    print(f"{'full plan, default settings (aim <= 10 s)':52s} {t:9.1f} s (median of {repeats})")
    print(f"{'  CPU time (process + worker processes)':52s} {cpu:9.1f} s ({cpu / t:.0%} of wall)")
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in plan.seconds.items())
    print(f"  stages of the last run: {stages}")
    print(f"  O1 planned {o['O1']:.4f} vs random at the same positions {r['O1']:.4f}; "
          f"condition {plan.observability.condition:.1f} vs "
          f"{plan.random_observability.condition:.1f}")  # fmt: skip


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cli_plan(code: Path, options: list[str]) -> tuple[float, float, float]:
    """`rvis plan` of the checkout `code` as its own process: (wall s, CPU s of the process
    and its worker processes, O1 of the plan)."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "plan.json"
        argv = [sys.executable, "-m", "app", "plan", "--out", str(out), *options]
        t, c = time.perf_counter(), _children_cpu()
        subprocess.run(argv, cwd=code, env=env, check=True, capture_output=True)
        wall, cpu = time.perf_counter() - t, _children_cpu() - c
        o1 = float(json.loads(out.read_text())["observability"]["O1"])
    return wall, cpu, o1


def bench_cli(reference: Path, repeats: int) -> None:
    here = Path(__file__).resolve().parents[1]
    variants = [
        ("reference: rvis plan", reference, []),
        ("this code: rvis plan", here, []),
        ("this code: rvis plan --patience 0", here, ["--patience", "0"]),
    ]
    runs: dict[str, list[tuple[float, float, float]]] = {name: [] for name, _, _ in variants}
    for k in range(repeats):
        for name, code, options in variants[k % 3 :] + variants[: k % 3]:
            runs[name].append(run_cli_plan(code, options))
            w, c, _ = runs[name][-1]
            print(f"  repeat {k + 1}: {name:36s} wall {w:6.1f} s, CPU {c:6.1f} s", flush=True)
    med = {n: [statistics.median(v[i] for v in r) for i in range(3)] for n, r in runs.items()}
    ref_wall, ref_cpu, _ = med["reference: rvis plan"]
    print(f"{'rvis plan (own process), median of ' + str(repeats):52s} {'wall':>9s} "
          f"{'CPU':>9s} {'wall/ref':>9s} {'CPU/ref':>9s} {'O1':>8s}")  # fmt: skip
    for name, (w, c, o1) in med.items():
        print(f"  {name:50s} {w:8.1f}s {c:8.1f}s {w / ref_wall:9.2f} {c / ref_cpu:9.2f} "
              f"{o1:8.5f}")  # fmt: skip
    print(f"  reference: {reference}; the runs alternate, the order rotating every repeat")


def bench_grid_check() -> None:
    cfg = load_cell(None)
    model = cfg.model()
    x = model.nominal_x()
    small: dict[str, Any] = {"swarm_size": 10, "iterations": 3, "workers": 1}
    out = {}
    for step in (30.0, 5.0):
        t0 = time.perf_counter()
        plan = run_plan(cfg, model, x, search_step_deg=step, **small)
        out[step] = (plan.observability.indices["O1"], time.perf_counter() - t0)
        print(f"  swarm 10 x 3 iterations, PSO fitness on the {step:g} deg grid: final O1 "
              f"{out[step][0]:.4f} in {out[step][1]:.0f} s")  # fmt: skip
    ratio = out[30.0][0] / out[5.0][0]
    print(f"{'coarse (30 deg) vs full (5 deg) fitness, final O1':52s} {100 * (ratio - 1):+8.2f} %"
          " (aim: within 2 %)")  # fmt: skip


def bench_ik() -> None:
    try:
        from bench import ik as ik_bench
    except ImportError as exc:
        print(f"IK benchmark unavailable: {exc}")
        return
    ik_bench.main()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-svd", action="store_true")
    ap.add_argument("--skip-grid-check", action="store_true")
    ap.add_argument("--skip-full", action="store_true")
    ap.add_argument("--skip-detmax", action="store_true")
    ap.add_argument("--skip-ik", action="store_true")
    ap.add_argument("--skip-cli", action="store_true")
    ap.add_argument(
        "--reference", type=Path, help="checkout to compare `rvis plan` with (e.g. main's)"
    )
    args = ap.parse_args()
    print(f"{'what':52s} {'median':>11s}")
    if not args.skip_detmax:
        bench_detmax(args.skip_svd, args.repeats)
    if not args.skip_full:
        bench_full_plan(args.repeats)
    if not args.skip_cli and args.reference:
        bench_cli(args.reference.resolve(), args.repeats)
    if not args.skip_grid_check:
        bench_grid_check()
    if not args.skip_ik:
        bench_ik()


if __name__ == "__main__":
    main()
