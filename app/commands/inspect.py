"""`rvis inspect plan`: a view for every feature of the part type on the calibrated robot and a
route through them (app/inspect/views.py).

Inputs default to a commissioned state directory's files (`--state-dir`, else the cell file's
`[service] state_dir`): `cell.toml`, `params/current.json`, `sensor.toml` and `features.toml`
(docs/inspection.md); each may be given instead (`--cell --params --sensor --features`).
Exit 0 every feature has a view, 3 a feature has none (named with the reason; the others are
planned and written all the same), 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from app.commands import add_command
from app.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "inspect")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True, parser_class=type(p))
    plan = verbs.add_parser(
        "plan",
        help="a view per feature on the calibrated robot and a route",
        description="a view per feature on the calibrated robot and a route through them",
    )
    plan.add_argument("--cell", help="cell file (default: STATE_DIR/cell.toml)")
    plan.add_argument("--state-dir", type=Path, help="a commissioned state directory")
    plan.add_argument("--params", type=Path, help="parameters JSON (default: the version in force)")
    plan.add_argument("--sensor", type=Path, help="sensor file (default: STATE_DIR/sensor.toml)")
    plan.add_argument(
        "--features", type=Path, help="feature plan (default: STATE_DIR/features.toml)"
    )
    plan.add_argument("--out", type=Path, help="write the route as JSON here")
    plan.add_argument("--json", action="store_true", help="print the route as JSON")
    plan.set_defaults(func=run_plan)


def _inputs(args: argparse.Namespace) -> tuple[Any, Path, Path, Path]:
    from app.config import load_cell
    from app.line.statedir import StateDir

    state = args.state_dir
    if state is None and not (args.params and args.sensor and args.features):
        state = Path(load_cell(args.cell).service.state_dir)
    paths = StateDir(state) if state is not None else None
    cell = args.cell or (str(paths.cell) if paths and paths.cell.is_file() else None)
    cfg = load_cell(cell)

    def pick(given: Path | None, default: Path | None, what: str, flag: str) -> Path:
        path = given or default
        if path is None or not path.is_file():
            where = f" in {paths.root}" if paths else ""
            raise InputError(
                f"no {what}{where}: give {flag} or a commissioned --state-dir",
                file=path,
                field=flag,
            )
        return path

    params = pick(args.params, paths.current if paths else None, "parameters", "--params")
    sensor = pick(args.sensor, paths.sensor if paths else None, "sensor file", "--sensor")
    features = pick(args.features, paths.features if paths else None, "feature plan", "--features")
    return cfg, params, sensor, features


def run_plan(args: argparse.Namespace) -> int:
    from app.api import Calibration
    from app.commands.sensor import load_model
    from app.formats.files import write_json
    from app.formats.jsontext import dumps_json
    from app.inspect.plan import load_features
    from app.inspect.views import in_window, plan_views, route_table

    cfg, params, sensor_path, features = _inputs(args)
    plan = load_features(features, cfg.T_part_base)
    cal = Calibration.load(params)
    sensor = load_model(sensor_path)
    if not args.json:
        print(
            f"rvis inspect plan: {len(plan.features)} features of {plan.part} on {params}",
            file=sys.stderr,
            flush=True,
        )
    route = plan_views(cfg.line, cfg.robot.repeatability_mm, cal.model, cal.x, plan, sensor)
    fit = in_window(route, cfg.line)
    doc = {
        "part": plan.part,
        "features": len(plan.features),
        "route_s": round(route.route_s, 2),
        "per_feature_s": round(route.route_s / max(len(route.views), 1), 2),
        "views": route_table(route),
        "unreachable": route.unreachable,
        "clamp_sd_mm": plan.clamp_sd_mm,
        "in_window": fit.as_dict(),
    }
    if args.out:
        write_json(args.out, doc)
    if args.json:
        print(dumps_json(doc, indent=2))
    else:
        for v, view in zip(route_table(route), route.views, strict=True):
            print(
                f"  {v['feature']:<8} tilt {v['tilt_deg']:4.0f} deg  repeat sd"
                f" {v['repeat_sd_mm']:.3f} mm  motion {v['motion_s']:.2f} s  sweep"
                f" {v['sweep_s']:.2f} s" + (f"  {view.stops} stops" if view.stops > 1 else "")
            )
        several = sum(v.stops > 1 for v in route.views)
        print(
            f"{len(route.views)} of {len(plan.features)} features planned"
            + (f" ({several} from several stops: the robot's repeatability)" if several else "")
            + f"; route {route.route_s:.1f} s from home and back"
            + (" with every stop" if several else "")
            + f" ({doc['per_feature_s']} s per feature)"
        )
        cut = f", {fit.features_cut} features cut: no time left" if fit.features_cut else ""
        print(
            f"in the body's window ([line] body_window_s {fit.window_s:g} s): {fit.robot_s:.1f} s,"
            f" {fit.extra_stops} of {fit.extra_stops_wanted} extra stops{cut} (an extra stop"
            " while the rest of the route still fits)"
        )
        print(
            f"the fixture's clamping repeatability {plan.clamp_sd_mm:g} mm in every position's U95"
            if plan.clamp_sd_mm > 0
            else "the fixture's clamping repeatability not given (clamp_sd_mm): the values' U95"
            " leave the clamping out"
        )
    for fid, why in route.unreachable.items():
        print(f"feature {fid}: no view: {why}", file=sys.stderr)
    return 3 if route.unreachable else 0
