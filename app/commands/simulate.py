"""`rvis simulate`: write a calibration and a validation set of the simulated cell.

Every sphere must be measured from the requested number of configurations and every value
must be finite; otherwise nothing is written and the command says which sphere could not be
measured (exit code 2: the cell file asks for something the simulated robot cannot do)."""

from __future__ import annotations

import argparse

from app.commands import add_command
from app.commands.args import int_at_least


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "simulate")
    p.add_argument("--out", required=True, help="folder to write the CSV files into")
    p.add_argument("--seed", type=int_at_least(0), help="default: [simulation] seed")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument(
        "--configs-per-sphere", type=int_at_least(1), help="default: [calibration] (paper: 6)"
    )
    p.add_argument("--validation", type=int_at_least(1), default=100, help="positions (100)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from app.config import load_cell
    from app.errors import InputError
    from app.formats.files import write_measurements, write_targets
    from app.sim.cell import check_complete, simulated_sets

    cfg = load_cell(args.cell)
    seed = cfg.simulation.seed if args.seed is None else args.seed
    n_each = args.configs_per_sphere or cfg.calibration.configs_per_sphere
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError("exists and is not a folder", file=out)
    sim = simulated_sets(cfg, seed, n_each=n_each, n_validation=args.validation)
    cal, val = sim.calibration, sim.validation
    check_complete(cal, {t: n_each for t in cfg.spheres_part_mm}, cfg.source)
    check_complete(val, {t: 1 for t in val.targets}, cfg.source, total=args.validation)
    for name, ds in (("calibration", cal), ("validation", val)):
        m = ds.measurements
        write_measurements(out / f"{name}_measurements.csv", m.targets, m.q_deg, m.c_sensor_mm)
        write_targets(out / f"{name}_targets.csv", ds.targets)
        print(
            f"{name}: {len(m)} measurements of {len(ds.targets)} targets -> "
            f"{out / f'{name}_measurements.csv'}, {out / f'{name}_targets.csv'}"
        )
    return 0
