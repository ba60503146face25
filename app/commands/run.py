"""`rvis run [--cell cell.toml] [--state-dir DIR] [--plan plan.json]`: the unattended in-line
service (DESIGN.md section 6) on the devices of the cell file. Logs are JSON lines on stdout;
operators use `rvis status` and `rvis ctl` (the control socket in the state directory)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from app.errors import InputError, RvisError


def register(sub: Any) -> None:
    p = sub.add_parser("run", help="the unattended in-line service")
    p.add_argument("--cell", help="cell configuration TOML (default: the embedded cell)")
    p.add_argument("--state-dir", help="state directory (default: [service] state_dir)")
    p.add_argument("--plan", help="plan JSON from `rvis plan` (default: STATE_DIR/plan.json)")
    p.add_argument("--params", help="starting parameters JSON when the state has none yet")
    p.add_argument("--sensor-model", help="sensor calibration file (default: the design model)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.config import load_cell
    from app.line.launch import build_service, json_logs, serve
    from app.line.measure import SweepSensor
    from app.line.settings import from_cell
    from app.line.station import Station
    from app.params import from_json
    from drivers.errors import DeviceConfigError, DeviceError
    from drivers.safety import SafetyGuard
    from vision.sensor_model import default_sensor_model, load_sensor_model

    cfg = load_cell(args.cell)
    settings = from_cell(cfg, args.state_dir)
    plan = Path(args.plan) if args.plan else settings.state_dir / "plan.json"
    if not plan.is_file():
        raise InputError("no plan file (write one with `rvis plan --out ...`)", file=plan)
    x0 = from_json(args.params)[1] if args.params else None
    sensor_model = load_sensor_model(args.sensor_model) if args.sensor_model else None
    try:
        station = Station.open(dict(cfg.devices), guard=SafetyGuard())
    except DeviceConfigError as exc:
        raise InputError(str(exc), file=cfg.source, field="devices") from exc
    except DeviceError as exc:
        raise RvisError(f"cannot open the devices: {type(exc).__name__}: {exc}") from exc
    with station:
        if station.camera is None or station.galvo is None:
            raise InputError("the service needs a camera and a galvo", field="devices")
        sensor = SweepSensor(
            station.camera,
            station.galvo,
            sensor_model or default_sensor_model(),
            settings.sweep,
            keep_frames=settings.raw_sweeps_keep > 0,
        )
        service = build_service(cfg, station, sensor, settings, plan, x0)
        json_logs()
        serve(service)
    return 0
