"""The rendered measuring chain taken apart, against the simulated truth: where a rendered body
value's error can come from before the robot's parameters are involved.

1. The calibrated sensor model (a state directory's `sensor.toml`, from a rendered
   commissioning) against the true sensor over the measuring volume: for points drawn in it,
   the pixel and galvo command the true sensor sees them at, triangulated with the model. The
   error's rigid part (a shift and a turn of the sensor frame) is absorbed by the hand-eye
   calibration, which identifies the sensor's frame on the spheres through this very model;
   what is left after the best rigid fit is what no calibration of the robot removes.
2. Sphere centres (the commissioning's plan's views, rendered as the line renders them): with
   the true sensor model (the rendering and the sphere fit alone) and with the calibrated one.
3. Feature centres on a bore plate (bench/edge.py's: a 12 mm hole and an 8 x 20 mm slot,
   tilted 0-15 degrees and rolled) with the true sensor model: in the plate's plane and along
   its normal, against the feature fit's own sd.

    .venv/bin/python bench/rendered_chain.py STATE_DIR [--seed 202] [--points 3000]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from app.config import load_cell
from app.sim.bodies import rendered_profiles
from app.sim.cell import make_cell, render_and_measure, true_sensor_model
from fakes.cell_spec import NotVisible
from fakes.render_sensor import TrueSensor
from fakes.render_sheet import bench_commands, bench_pose
from vision.errors import FeatureRefused
from vision.features import measure_feature
from vision.sensor_model import SensorModel, load_sensor_model
from vision.triangulate import intersect_planes, pixel_rays

F64 = NDArray[np.float64]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("state", type=Path, help="a rendered commissioning's state directory")
    p.add_argument("--seed", type=int, default=202, help="the cell's seed")
    p.add_argument("--points", type=int, default=3000)
    args = p.parse_args()
    cfg = load_cell(args.state / "cell.toml")
    cell = make_cell(cfg, seed=args.seed)
    model = load_sensor_model(args.state / "sensor.toml")
    true_model = true_sensor_model(cell.sensor)
    um = 1e3
    P, E = model_field(cell.sensor, model, args.points)
    r = rigid_residual(P, E)
    print(f"1. the sensor model over the measuring volume ({len(P)} points), um, x / y / z:")
    print(f"   raw error: mean {_um(E.mean(0))}, RMS {_rms3(um * E)}")
    print(f"   after the best rigid fit: RMS {_rms3(um * r)}, max {_um(abs(r).max(0))}")
    views = [
        (np.asarray(s["position_part_mm"], float), np.asarray(c["q_deg"], float))
        for s in json.loads((args.state / "plan.json").read_text())["spheres"]
        for c in s["configurations"]
    ]
    a, b, c = [], [], []
    for p_part, q in views:
        for _ in range(2):
            try:
                job = cell.sweep_job(q, p_part)
            except NotVisible:  # the plan's view of a sphere placed elsewhere in this world
                continue
            got_true = render_and_measure(job, cell.sensor, true_model).c_sensor_mm
            got_cal = render_and_measure(job, cell.sensor, model).c_sensor_mm
            if got_true is not None and got_cal is not None:
                a.append(got_true - job.c_sensor_mm)
                b.append(got_cal - job.c_sensor_mm)
                c.append(job.c_sensor_mm)
    A, B = np.array(a), np.array(b)
    rb = rigid_residual(np.array(c), B)
    print(f"2. sphere centres ({len(A)} sweeps), um, x / y / z:")
    print(f"   true sensor model: mean {_um(A.mean(0))}, sd {_um(A.std(0))}")
    print(f"   calibrated model: mean {_um(B.mean(0))}, sd {_um(B.std(0))}")
    print(f"   calibrated model after the best rigid fit: RMS {_rms3(um * rb)}")
    print("3. bore plate feature centres, true sensor model, um (in plane u / v, normal):")
    for kind, size, err, sd in feature_centres(cell.sensor, true_model):
        print(
            f"   {kind} {'x'.join(f'{s:g}' for s in size)} ({len(err)} sweeps): mean"
            f" {_um(err.mean(0))}, RMS {_rms3(um * err)}, RMS sd_fit {_rms3(um * sd)}"
        )


def model_field(true: TrueSensor, model: SensorModel, n: int) -> tuple[F64, F64]:
    """Points (n, 3) drawn in the measuring volume (camera frame) and the model's error at each
    (triangulated from the true sensor's pixel and command, less the point)."""
    rng = np.random.default_rng(0)
    pts, errs = [], []
    for _ in range(n):
        X = np.array([rng.uniform(-18, 18), rng.uniform(-13, 13), rng.uniform(125, 135)])
        v = _command_through(true, X)
        uv = true.project(X)
        if v is None or not (0 <= uv[0] < true.width_px and 0 <= uv[1] < true.height_px):
            continue
        normal, offset = model.laser.planes(np.array([v]))
        got = intersect_planes(pixel_rays(model.camera, uv[None]), normal, np.atleast_1d(offset))
        pts.append(X)
        errs.append(got[0] - X)
    return np.array(pts), np.array(errs)


def _command_through(true: TrueSensor, X: F64) -> float | None:
    """The galvo command [V] whose true laser plane holds X (None: none in +-10 V)."""

    def f(v: float) -> float:
        n, d = true.laser_planes(np.array([v]))
        return float(n[0] @ X - d[0])

    vs = np.linspace(-10.0, 10.0, 81)
    fs = [f(v) for v in vs]
    for lo, hi, f_lo, f_hi in zip(vs[:-1], vs[1:], fs[:-1], fs[1:], strict=True):
        if f_lo * f_hi <= 0:
            return float(brentq(f, lo, hi))
    return None


def rigid_residual(P: F64, E: F64) -> F64:
    """What is left of errors E at points P after the best rigid motion (Kabsch)."""
    A, B = P, P + E
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)))])
    R = Vt.T @ D @ U.T
    out: F64 = B - ((A - ca) @ R.T + cb)
    return out


def feature_centres(
    true: TrueSensor, model: SensorModel
) -> list[tuple[str, tuple[float, ...], F64, F64]]:
    """Per feature: its centre errors (n, 3) in the plate's axes and the fit's own sd (n, 3)."""
    out = []
    for kind, size in (("hole", (12.0,)), ("slot", (8.0, 20.0))):
        cmds = bench_commands(true, 0.5 * max(size) + 3.0, 40)
        errs, sds = [], []
        for tilt in (0.0, 5.0, 10.0, 15.0):
            for roll in (0.0, 30.0, 75.0):
                T = bench_pose(tilt, roll)
                R, t = T[:3, :3], T[:3, 3]
                for seed in range(2):
                    rng = np.random.default_rng([seed, int(tilt), int(roll), int(10 * size[0])])
                    prof = rendered_profiles(T, kind, size, 1.2, true, model, rng, cmds)
                    try:
                        fit = measure_feature(kind, prof, t, R[:, 2], size, R[:, 0])
                    except FeatureRefused:
                        continue
                    errs.append(R.T @ (fit.centre_mm - t))
                    sds.append(np.sqrt(np.diag(R.T @ fit.cov_centre_mm2 @ R)))
        out.append((kind, size, np.array(errs), np.array(sds)))
    return out


def _um(v: F64) -> list[float]:
    return [round(1e3 * float(x), 1) for x in v]


def _rms3(a: F64) -> list[float]:
    return [round(math.sqrt(float(np.mean(a[:, k] ** 2))), 1) for k in range(3)]


if __name__ == "__main__":
    main()
