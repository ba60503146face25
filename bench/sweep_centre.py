"""One sweep -> sphere centre (vision only, one core): the current code against the vision package
of an earlier commit, in the same process on the same frames, runs interleaved so that both see
the same machine load. Medians of repeated runs and their ratio, per stage and whole; the
centres of both must agree (printed) and are compared with the renderer's truth.

    nice -n 5 .venv/bin/python bench/sweep_centre.py [--before REV] [--repeats 21]

The sweep is the one of bench/line.py (the issue's figure: the default cell, seed 3, the first
planned view of P1, 24 frames of 1296x966). The earlier package is read with `git show REV:...`
into a temporary directory as the package `vision_before`.
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.threads import limit_blas_threads

limit_blas_threads()

import cv2
import numpy as np

#: The branch point of the speed-up (issue 11 leftovers): the vision package before it.
DEFAULT_BEFORE = "f662049"


def load_before(rev: str, into: Path) -> ModuleType:
    """The vision package at `rev` as `vision_before` (its own imports rewritten)."""
    pkg = into / "vision_before"
    pkg.mkdir()
    names = subprocess.run(
        ["git", "ls-tree", "--name-only", rev, "vision/"],
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    for name in names:
        text = subprocess.run(
            ["git", "show", f"{rev}:{name}"], cwd=ROOT, check=True, capture_output=True, text=True
        ).stdout
        text = text.replace("from vision.", "from vision_before.").replace(
            "import vision.", "import vision_before."
        )
        (pkg / Path(name).name).write_text(text)
    sys.path.insert(0, str(into))
    return importlib.import_module("vision_before.measure")


def the_sweep() -> tuple[Any, Any, Any]:
    from app.config import load_cell
    from app.sim.cell import make_cell
    from tests.line.helpers import plan_for

    cfg = load_cell(None)
    cell = make_cell(cfg, 3)
    q = plan_for(3)["P1"][0]
    frames, commands, _ = cell.render_sweep(q, cfg.spheres_part_mm["P1"])
    truth = cell.centre_in_sensor(q[None], cfg.spheres_part_mm["P1"])[0]
    return np.asarray(frames), np.asarray(commands), truth


def stages(m: ModuleType, frames: Any, cmds: Any, model: Any) -> dict[str, Callable[[], Any]]:
    """The pipeline of measure module `m` cut into its stages (each a thunk)."""
    pkg = m.__name__.rsplit(".", 1)[0]
    stripe = importlib.import_module(f"{pkg}.stripe")
    tri = importlib.import_module(f"{pkg}.triangulate")
    fit = importlib.import_module(f"{pkg}.spherefit")
    if hasattr(stripe, "extract_sweep"):
        stripes = stripe.extract_sweep(frames)
        extract = lambda: stripe.extract_sweep(frames)  # noqa: E731
    else:
        stripes = [stripe.extract_stripe(f) for f in frames]
        extract = lambda: [stripe.extract_stripe(f) for f in frames]  # noqa: E731
    X, _ = tri.triangulate_sweep(stripes, cmds, model)
    return {
        "stripe extraction (24 frames)": extract,
        "triangulation": lambda: tri.triangulate_sweep(stripes, cmds, model),
        "sphere fit": lambda: fit.fit_sphere(X, 15.0),
        "whole: sweep -> centre": lambda: m.measure_sphere_from_sweep(frames, cmds, model),
    }


def timed(fn: Callable[[], Any]) -> tuple[float, float]:
    """(wall, CPU) seconds of one call: on a shared machine the CPU time follows the load less."""
    t, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t, time.process_time() - c


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--before", default=DEFAULT_BEFORE, help="git revision of the earlier code")
    p.add_argument("--repeats", type=int, default=21)
    args = p.parse_args(argv)
    cv2.setNumThreads(1)
    from vision import measure as after
    from vision.sensor_model import default_sensor_model

    frames, cmds, truth = the_sweep()
    model = default_sensor_model()
    with tempfile.TemporaryDirectory() as tmp:
        before = load_before(args.before, Path(tmp))
        model_b = importlib.import_module("vision_before.sensor_model").default_sensor_model()
        runs = {
            "before": stages(before, frames, cmds, model_b),
            "after": stages(after, frames, cmds, model),
        }
        times: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for _ in range(args.repeats):
            for stage in runs["after"]:
                for who in ("before", "after"):  # interleaved: the same load for both
                    times.setdefault((who, stage), []).append(timed(runs[who][stage]))
        c_b = before.measure_sphere_from_sweep(frames, cmds, model_b).c_sensor_mm
    c_a = after.measure_sphere_from_sweep(frames, cmds, model).c_sensor_mm
    width = max(len(s) for s in runs["after"])
    print(f"medians of {args.repeats} interleaved runs, one core; before = {args.before}")
    print(f"{'':<{width}}  {'wall ms':^28}  {'CPU ms':^28}")
    print(f"{'stage':<{width}}" + "  before    after  after/before" * 2)
    for stage in runs["after"]:
        cells = []
        for k in (0, 1):  # wall, CPU
            b = 1000 * statistics.median(t[k] for t in times[("before", stage)])
            a = 1000 * statistics.median(t[k] for t in times[("after", stage)])
            cells.append(f"  {b:6.1f}  {a:7.1f}  {a / b:12.2f}")
        print(f"{stage:<{width}}" + "".join(cells))
    print(
        f"centre after - before: {1e6 * np.abs(c_a - c_b).max():.3f} nm (max |component|); "
        f"error vs truth: before {1000 * np.linalg.norm(c_b - truth):.2f} um, "
        f"after {1000 * np.linalg.norm(c_a - truth):.2f} um"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
