"""Benchmark of the step attribution (calib.attribution): one attribution (every candidate group
fitted, target <= 50 ms on one core) against a full 30-parameter identification on the same
data (12 measurements after a sensor knock; 6, as a first fast correction has, for the
attribution alone: 18 equations do not determine 30 parameters), measured in the same run and
interleaved (so that the ratio holds on a loaded machine). Prints medians of repeated runs.
BLAS runs on one thread (app.threads), as in the service.

    nice -n 5 .venv/bin/python bench/attribution.py
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.threads import limit_blas_threads

limit_blas_threads()

import numpy as np

from app.config import load_cell
from app.sim.cell import make_cell
from calib import candidates
from calib.attribution import attribute
from calib.identify import Measurements, identify, residuals
from calib.model import SystemModel
from fakes.clock import ScaledClock
from fakes.truth import Knock

AIM_S = 0.050
REPEATS = 15


def _data(n: int) -> tuple[SystemModel, np.ndarray, Measurements, np.ndarray]:
    """n views of the simulated cell before and after a sensor knock: (model, parameters
    identified before, the measurements after, their references before)."""
    cfg = load_cell(None)
    model = cfg.model()
    cell = make_cell(cfg, seed=0)
    cell.set_timeline(ScaledClock(1.0, started=False), knock=Knock.of_kind("sensor", 100.0))
    rng = np.random.default_rng(1)
    ids = sorted(cfg.spheres_part_mm)
    qs, ps, tids = [], [], []
    for k in range(max(n, 24)):
        tid = ids[k % len(ids)]
        p = cfg.spheres_part_mm[tid]
        qs.append(candidates.random_configurations(model, model.nominal_x(), p, 1, rng).q_deg[0])
        ps.append(p)
        tids.append(tid)
    q, p_arr = np.array(qs), np.array(ps)

    def measure(t_s: float) -> np.ndarray:
        c = np.array(
            [cell.centre_in_sensor(qi[None], pi, t_s)[0] for qi, pi in zip(q, p_arr, strict=True)]
        )
        return c + rng.normal(0.0, 0.02, c.shape)

    before = Measurements(q, measure(0.0), p_arr, tuple(tids))
    after = Measurements(q, measure(200.0), p_arr, tuple(tids))
    x = identify(model, before).x
    rows = np.arange(n)
    return model, x, after.subset(rows), residuals(model, x, before.subset(rows))


def interleaved(fns: list[Callable[[], object]], repeats: int) -> list[float]:
    """Median seconds of each function, run in turn (the load falls on all alike)."""
    for fn in fns:
        fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return [statistics.median(t) for t in times]


def main() -> None:
    import os

    print(f"{'what':66s} {'median':>9s} {'aim':>8s} {'/ ident.':>9s}")
    model, x, after, ref = _data(12)
    sigma = 0.02 * np.sqrt(2.0)
    six = np.arange(6)
    t12, t6, t_id = interleaved(
        [
            lambda: attribute(model, x, after, sigma_mm=sigma, reference_mm=ref),
            lambda: attribute(model, x, after.subset(six), sigma_mm=sigma, reference_mm=ref[six]),
            lambda: identify(model, after, x0=x),
        ],
        REPEATS,
    )
    for what, t in (
        ("one attribution, 12 measurements (8 candidates, the full set too)", t12),
        ("one attribution, 6 measurements (7 candidates determined)", t6),
    ):
        print(f"{what:66s} {1e3 * t:7.1f} ms {1e3 * AIM_S:5.0f} ms {t / t_id:8.2f}x")
    print(
        f"{'identification of the 30 parameters, the same 12 measurements':66s}"
        f" {1e3 * t_id:7.1f} ms {'':>8s} {1.0:8.2f}x"
    )
    print(f"({os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}, {REPEATS} repeats)")


if __name__ == "__main__":
    main()
