"""`rvis simulate`: write a calibration and a validation set of the simulated cell."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from app.config import load_cell
from app.files import write_measurements, write_targets
from app.simulation import collect, make_cell, validation_set


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="write simulated calibration and validation sets")
    p.add_argument("--out", required=True, help="folder to write the CSV files into")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell (default 0)")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--configs-per-sphere", type=int, default=6, help="default 6 (paper)")
    p.add_argument("--validation", type=int, default=100, help="validation positions (100)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_cell(args.cell)
    cell = make_cell(cfg, seed=args.seed)
    model = cfg.model()
    x0 = model.nominal_x()
    rng = np.random.default_rng([args.seed, 2])
    out = Path(args.out)
    cal = collect(cell, model, x0, cfg.spheres_part_mm, args.configs_per_sphere, rng)
    val = validation_set(cell, cfg, model, x0, args.validation, rng)
    for name, ds in (("calibration", cal), ("validation", val)):
        m = ds.measurements
        write_measurements(out / f"{name}_measurements.csv", m.targets, m.q_deg, m.c_sensor_mm)
        write_targets(out / f"{name}_targets.csv", ds.targets)
        print(
            f"{name}: {len(m)} measurements of {len(ds.targets)} targets -> "
            f"{out / f'{name}_measurements.csv'}, {out / f'{name}_targets.csv'}"
        )
    return 0
