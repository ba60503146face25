"""`rvis sensor calibrate DIR --out sensor.toml` and `rvis sensor measure SWEEP_DIR`.

Recorded data on disk (PNG frames, 8 or 16 bit; commands in volts):

    SWEEP_DIR/commands.csv        header `frame,command_v`; one row per frame: PNG file name
                                  (relative to SWEEP_DIR) and the galvo command it was taken at
    CALIB_DIR/chessboards/*.png   chessboard views for the intrinsics
    CALIB_DIR/targets/<pose>/board.png      the flat target's chessboard at that pose
    CALIB_DIR/targets/<pose>/commands.csv   a sweep over the target's white face (as above)

Exit codes: 0 ok; 2 bad input (file, line, field named), including calibration data that do
not determine the sensor; 3 a measurement rejected by its quality checks.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commands import add_command
from app.commands.args import float_in, sim_seed
from app.config.tomlfile import read_toml
from app.errors import InputError, QualityError
from app.formats.files import check_output, write_text
from app.formats.sweeps import calibrate_dir, read_sweep
from vision.errors import SensorFileError, VisionError
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import (
    SensorModel,
    default_sensor_model,
    dumps_sensor_model,
    sensor_model_from_dict,
)


def register(subparsers: Any) -> None:
    """Add `rvis sensor {calibrate,measure}`."""
    parser = add_command(subparsers, "sensor")
    parser.add_argument(
        "--mode",
        choices=["fast", "precise"],
        default="fast",
        help="stripe extraction: fast (windowed centroid, default) or precise (Steger)",
    )
    sub = parser.add_subparsers(dest="sensor_command", metavar="ACTION", required=True)
    cal = sub.add_parser("calibrate", help="calibrate the sensor from recorded images")
    cal.add_argument("dir", type=Path, help="folder with chessboards/ and targets/<pose>/")
    cal.add_argument("--out", type=Path, required=True, help="sensor calibration TOML to write")
    cal.add_argument("--pattern", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    cal.add_argument(
        "--square-mm", type=float_in(0.0, 1000.0), default=2.5, help="square size [mm]"
    )
    cal.set_defaults(func=run_calibrate)
    mea = sub.add_parser("measure", help="measure a sphere centre from one recorded sweep")
    mea.add_argument("sweep_dir", type=Path, help="folder with commands.csv and the PNG frames")
    mea.add_argument("--sensor", type=Path, help="sensor calibration TOML (default: simulated)")
    mea.add_argument(
        "--radius-mm",
        type=float_in(0.0, 1000.0, open_lo=False),
        default=15.0,
        help="certified sphere radius [mm]; 0 fits a free radius",
    )
    mea.add_argument("--json", action="store_true", help="print the result as JSON")
    mea.set_defaults(func=run_measure)
    ver = sub.add_parser(
        "verify",
        help="the sensor's acceptance test on the cell (adapted from VDI/VDE 2634-2: PF, PS, SD)",
        description="Measure one of the cell's spheres at 9 positions across the sensor's "
        "measuring volume (the robot moves the sensor without turning it) and hold the "
        "probing errors form PF and size PS and the sphere-spacing error SD to [sensor] "
        "max_pf_mm, max_ps_mm, max_sd_mm. Needs the devices (the service stopped). Results in "
        "STATE_DIR/verify/. Exit 0 passed, 3 failed, 1 stopped, 2 bad input.",
    )
    ver.add_argument("--cell", type=Path, help="cell TOML (default: STATE_DIR/cell.toml)")
    ver.add_argument("--state-dir", type=Path, help="state directory (default: [service])")
    ver.add_argument("--sensor", type=Path, help="sensor TOML (default: STATE_DIR/sensor.toml)")
    ver.add_argument("--params", type=Path, help="parameters (default: the ones in force)")
    ver.add_argument("--yes", action="store_true", help="confirm every motion")
    ver.add_argument("--sim", action="store_true", help="on the simulated line (no hardware)")
    ver.add_argument("--seed", type=int, help="--sim: seed (default [simulation])")
    ver.add_argument("--json", action="store_true", help="print the result as JSON")
    ver.set_defaults(func=run_verify)


def load_model(path: Path | None) -> SensorModel:
    if path is None:
        return default_sensor_model()
    doc, _ = read_toml(path)
    try:
        return sensor_model_from_dict(doc)
    except SensorFileError as exc:
        raise InputError(exc.reason, file=path, field=exc.field) from exc


def _check_size(frames: list[NDArray[np.generic]], model: SensorModel, where: Path) -> None:
    want = (model.camera.height_px, model.camera.width_px)
    for frame in frames:
        if frame.shape != want:
            raise InputError(
                f"frame size {frame.shape[1]}x{frame.shape[0]} differs from the "
                f"sensor's {want[1]}x{want[0]}",
                file=where,
            )


def run_measure(args: argparse.Namespace) -> int:
    """Measure one sphere; prints the centre in the sensor frame [mm]."""
    model = load_model(args.sensor)
    frames, commands = read_sweep(args.sweep_dir)
    _check_size(frames, model, args.sweep_dir)
    radius = args.radius_mm if args.radius_mm > 0 else None
    try:
        m = measure_sphere_from_sweep(
            frames, commands, model, certified_radius_mm=radius, mode=args.mode
        )
    except VisionError as exc:
        raise QualityError(f"{args.sweep_dir}: measurement rejected: {exc}") from exc
    sigma_um = np.sqrt(np.diag(m.cov_mm2)) * 1000.0
    q = m.quality
    if args.json:
        print(
            json.dumps(
                {
                    "c_sensor_mm": m.c_sensor_mm.tolist(),
                    "cov_mm2": m.cov_mm2.tolist(),
                    "radius_mm": m.radius_mm,
                    "status": m.status,
                    "quality": q.__dict__,
                    "n_frames_used": m.n_frames_used,
                }
            )
        )
    else:
        x, y, z = m.c_sensor_mm
        print(
            f"centre_sensor_mm {x:.4f} {y:.4f} {z:.4f}  sigma_um {sigma_um[0]:.1f} "
            f"{sigma_um[1]:.1f} {sigma_um[2]:.1f}  points {q.n_points}  rms_um "
            f"{q.rms_mm * 1000:.1f}  free_radius_mm {q.radius_free_mm:.4f}"
        )
    return 0


def run_verify(args: argparse.Namespace) -> int:
    """`rvis sensor verify`: the acceptance step of the commissioning, alone."""
    from contextlib import ExitStack

    from app.commands.guided import commissioning_context, confirmation, printer
    from app.commission.acceptance import verify
    from app.commission.checks import StepResult
    from app.commission.report import check_line
    from app.config import load_cell
    from app.formats.params import from_json
    from app.line.launch import hold_state
    from app.line.statedir import StateDir
    from vision.sensor_model import load_sensor_model

    if args.seed is not None and not args.sim:
        raise InputError("--seed needs --sim")
    state_dir = args.state_dir or Path(load_cell(args.cell).service.state_dir)
    paths = StateDir(state_dir)
    cell_path = args.cell or (paths.cell if paths.cell.is_file() else None)
    cfg = load_cell(cell_path)
    sensor_path = args.sensor or paths.sensor
    params_path = args.params or paths.current
    for what, path in (("sensor calibration", sensor_path), ("parameters", params_path)):
        if not Path(path).is_file():
            raise InputError(f"no {what}: commission the cell first (rvis commission)", file=path)
    sensor_model, x = load_sensor_model(sensor_path), from_json(params_path)[1]
    say = printer(sys.stderr if args.json else sys.stdout)
    seed = sim_seed(args.seed, cfg, None if args.cell else cell_path)
    opts = argparse.Namespace(
        sim=args.sim, geometric=False, sensor=None, sensor_data=None, targets=None
    )
    with hold_state(state_dir, str(cfg.service.operators_group)) as state, ExitStack() as stack:
        ctx = commissioning_context(opts, cfg, state, seed, confirmation(args.yes, say), say, stack)
        ctx.out_dir = state.verify
        ctx.out_dir.mkdir(exist_ok=True)
        from app.commission.checks import holds
        from app.commission.context import Declined
        from drivers.errors import DeviceError

        try:
            result: StepResult = verify(ctx, x, sensor_model)
        except Declined as exc:
            say(f"stopped: not confirmed: {exc}")
            return 1
        except DeviceError as exc:  # as the commissioning's step records it: a failed check
            result = StepResult(checks=[holds("devices", False, f"{type(exc).__name__}: {exc}")])
    if args.json:
        doc = {"passed": result.passed, "results": result.results}
        doc["checks"] = [c.__dict__ for c in result.checks]
        print(json.dumps(doc, indent=2))
    else:
        for c in result.checks:
            print(check_line(c))
        for why in result.results.get("rejected", []):
            print(f"rejected: {why}")
        where = f"; per position: {ctx.out_dir / result.files[0]}" if result.files else ""
        print(f"sensor {'passed' if result.passed else 'FAILED'} its acceptance test{where}")
    return 0 if result.passed else 3


def run_calibrate(args: argparse.Namespace) -> int:
    """Calibrate from CALIB_DIR and write the sensor TOML."""
    check_output(args.out)
    model = calibrate_dir(args.dir, args.pattern, args.square_mm, args.mode)
    write_text(args.out, dumps_sensor_model(model))
    K = model.camera.K
    print(
        f"wrote {args.out}: fx {K[0, 0]:.2f} px, fy {K[1, 1]:.2f} px, reprojection "
        f"{model.camera.rms_reprojection_px:.3f} px, laser plane rms "
        f"{model.laser.rms_plane_mm:.4f} mm"
    )
    return 0
