"""`rvis plan`: where the spheres should stand and from which configurations to measure them."""

from __future__ import annotations

import argparse
import json
import sys

from app.commands import add_command
from app.config import load_cell
from app.formats.files import check_output, write_json
from app.formats.params import from_json
from app.formats.report import index_rows, text_table
from app.meta import provenance
from app.planning import (
    ProgressLine,
    add_plan_options,
    plan_overrides,
    plan_to_json,
    run_plan,
)
from calib.observability import INDEX_NAMES


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "plan")
    p.add_argument("--out", required=True, help="plan JSON to write")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--params", help="pre-calibrated parameters JSON to plan on (default: nominal)")
    p.add_argument(
        "--allow-failed", action="store_true", help="plan on parameters that failed their gates"
    )
    add_plan_options(p)
    p.add_argument("--seed", type=int, help="seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the plan summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output(args.out)
    cfg = load_cell(args.cell)
    if args.params:
        model, x = from_json(args.params, allow_failed=args.allow_failed)
    else:  # the model the cell identifies ([calibration] model): its parameters are planned for
        model = cfg.identification_model()
        x = model.nominal_x()
    overrides = plan_overrides(args)
    if args.seed is not None:
        overrides["seed"] = args.seed
    progress = ProgressLine(sys.stderr, str(args.criterion or cfg.planning["criterion"]))
    if not args.json:
        print(
            f"rvis plan: {cfg.source}, planning on {args.params or 'nominal parameters'} for"
            f" the {model.kind} model ({len(model.default_active())} parameters)",
            flush=True,
        )
    result = run_plan(cfg, model, x, progress=progress, **overrides)
    doc = {**plan_to_json(cfg, model, x, result), "provenance": provenance(result.settings.seed)}
    write_json(args.out, doc)
    if args.json:
        print(
            json.dumps({k: doc[k] for k in ("spheres", "observability", "random_plan", "seconds")})
        )
        return 0
    rows = [
        [sp["name"], *(f"{v:.1f}" for v in sp["position_base_mm"]), str(sp["n_candidates"])]
        for sp in doc["spheres"]
    ]
    print(text_table(["sphere", "x_base_mm", "y_base_mm", "z_base_mm", "candidates"], rows))
    print()
    conf_rows = []
    for sp in doc["spheres"]:
        for c in sp["configurations"]:
            conf_rows.append(
                [
                    sp["name"],
                    *(f"{v:.2f}" for v in c["q_deg"]),
                    *(f"{v:.1f}" for v in c["c_sensor_mm"]),
                ]
            )
    header = ["sphere", *(f"J{i}_deg" for i in range(1, 7)), "sx_mm", "sy_mm", "sz_mm"]
    print(text_table(header, conf_rows))
    print()
    idx = {"planned": doc["observability"], "random, same positions": doc["random_plan"]}
    print(text_table(["configurations", *INDEX_NAMES], index_rows(idx)))
    cond = {k: v["condition"] for k, v in idx.items()}
    print(
        f"\nrank {doc['observability']['rank']}, condition planned {cond['planned']:.1f}, "
        f"random {cond['random, same positions']:.1f}; "
        + ", ".join(f"{k} {v:.1f} s" for k, v in result.seconds.items())
    )
    print(f"written {args.out}")
    return 0
