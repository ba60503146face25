"""Benchmark of the calibration core: one identification (24 measurements) with the analytic
Jacobian vs finite differences (the reference, same run), and forward kinematics of 100k
configurations. Prints medians of repeated runs.

    .venv/bin/python bench/identify.py
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point, before numpy loads

import numpy as np

from app.config import load_cell
from app.sim.cell import collect, make_cell
from calib.identify import identify


def median_seconds(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    cfg = load_cell(None)
    model = cfg.model()
    x0 = model.nominal_x()
    cell = make_cell(cfg, seed=0)
    cal = collect(cell, model, x0, cfg.spheres_part_mm, 6, np.random.default_rng(0))
    data = cal.measurements
    q = np.random.default_rng(1).uniform(
        model.limits.lower_deg, model.limits.upper_deg, (100_000, 6)
    )
    rows = [
        ("identification, analytic Jacobian (24 meas.)", 20,
         lambda: identify(model, data), 0.020),
        ("identification, finite differences (reference)", 20,
         lambda: identify(model, data, jac="2-point"), None),
        ("FK T_part_sensor, 100k configurations", 10, lambda: model.fk(x0, q), 0.200),
    ]  # fmt: skip
    results = {}
    print(f"{'what':52s} {'median':>10s} {'aim':>8s}")
    for name, reps, fn, aim in rows:
        t = median_seconds(fn, reps)
        results[name] = t
        aim_s = f"<= {aim * 1e3:.0f} ms" if aim else ""
        print(f"{name:52s} {t * 1e3:8.2f} ms {aim_s:>8s}")
    ratio = results[rows[1][0]] / results[rows[0][0]]
    print(f"analytic vs finite-difference identification: {ratio:.1f}x faster")
    r_a = identify(model, data)
    r_f = identify(model, data, jac="2-point")
    print(f"same solution: max |x_analytic - x_fd| = {np.abs(r_a.x - r_f.x).max():.2e}, "
          f"nfev {r_a.nfev} vs {r_f.nfev}")  # fmt: skip


if __name__ == "__main__":
    main()
