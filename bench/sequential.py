"""Benchmark of the accuracy work: one sequential (Kalman) update with the rigid and with the
compliant model (target <= 2 ms), and one batch identification with each (same data, same
run, so the ratio holds on a loaded machine). Prints medians of repeated runs.

    nice -n 5 .venv/bin/python bench/sequential.py
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import load_cell
from app.sim.accuracy import measure_views, plan_views
from app.sim.cell import make_cell
from calib.compliance import CompliantModel
from calib.identify import Measurements, identify
from calib.model import SystemModel
from calib.sequential import SequentialEstimator

UPDATE_AIM_S = 0.002


def median_seconds(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def update_seconds(models: list[SystemModel], data: Measurements, repeats: int = 5) -> list[float]:
    """Median time of one update per model, the models' updates interleaved (so that the
    machine's load falls on both alike); the rigid model is not given the temperatures."""
    ests = [SequentialEstimator.from_result(m, identify(m, data)) for m in models]
    times: list[list[float]] = [[] for _ in models]
    for _ in range(repeats):
        for i in range(len(data)):
            for k, est in enumerate(ests):
                temp = None if est.model.kind == "rigid" or data.temp_c is None else data.temp_c[i]
                t = time.perf_counter()
                est.update(data.q_deg[i], data.c_sensor_mm[i], data.p_part_mm[i], temp)
                times[k].append(time.perf_counter() - t)
    return [statistics.median(t) for t in times]


def main() -> None:
    cfg = load_cell(None)
    rigid = cfg.model()
    compliant = CompliantModel.of(rigid)
    cell = make_cell(cfg, seed=0)
    rng = np.random.default_rng(0)
    views = plan_views((cell,), rigid, cfg.spheres_part_mm, 10, (20.0, 30.0), rng)
    data = measure_views(cell, views).measured
    no_temp = Measurements(data.q_deg, data.c_sensor_mm, data.p_part_mm, data.targets)
    t_rigid, t_compliant = update_seconds([rigid, compliant], data)
    rows = [
        ("sequential update, rigid (30 parameters)", t_rigid, True),
        ("sequential update, compliant + temperature (34)", t_compliant, True),
        (
            f"identification, rigid ({len(data)} meas.)",
            median_seconds(lambda: identify(rigid, no_temp), 10),
            False,
        ),
        (
            f"identification, compliant + temperature ({len(data)} meas.)",
            median_seconds(lambda: identify(compliant, data), 10),
            False,
        ),
    ]
    print(f"{'what':58s} {'median':>10s} {'aim':>9s}")
    for name, t, aimed in rows:
        aim = f"<= {UPDATE_AIM_S * 1e3:.0f} ms" if aimed else ""
        print(f"{name:58s} {t * 1e3:8.2f} ms {aim:>9s}")
    print(f"compliant vs rigid update: {rows[1][1] / rows[0][1]:.2f}x")
    print(f"compliant vs rigid identification: {rows[3][1] / rows[2][1]:.2f}x")


if __name__ == "__main__":
    main()
