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
import csv
import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.cliargs import float_in
from app.errors import InputError, QualityError
from app.files import check_output, write_text
from app.tomlfile import read_toml
from vision.calibrate import Chessboard
from vision.calibrate_sensor import calibrate_sensor
from vision.errors import CalibrationFailed, SensorFileError, VisionError
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import (
    SensorModel,
    default_sensor_model,
    dumps_sensor_model,
    sensor_model_from_dict,
)

SWEEP_HEADER = ["frame", "command_v"]


def register(subparsers: Any) -> None:
    """Add `rvis sensor {calibrate,measure}`."""
    parser = subparsers.add_parser("sensor", help="laser-line sensor: calibrate, measure")
    sub = parser.add_subparsers(dest="sensor_command", metavar="ACTION", required=True)
    cal = sub.add_parser("calibrate", help="calibrate the sensor from recorded images")
    cal.add_argument("dir", type=Path, help="folder with chessboards/ and targets/<pose>/")
    cal.add_argument("--out", type=Path, required=True, help="sensor calibration TOML to write")
    cal.add_argument("--pattern", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    cal.add_argument(
        "--square-mm", type=float_in(0.0, 1000.0), default=2.5, help="square size [mm]"
    )
    cal.add_argument("--mode", choices=["fast", "precise"], default="fast")
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
    mea.add_argument("--mode", choices=["fast", "precise"], default="fast")
    mea.add_argument("--json", action="store_true", help="print the result as JSON")
    mea.set_defaults(func=run_measure)


def read_image(path: Path) -> NDArray[np.generic]:
    """A grey PNG (8 or 16 bit) as a 2-D array; InputError names the file."""
    if not path.is_file():
        raise InputError("image file not found", file=path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError("not a readable image", file=path)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return np.asarray(image)


def read_sweep(sweep_dir: Path) -> tuple[list[NDArray[np.generic]], NDArray[np.float64]]:
    """Frames and commands [V] of a recorded sweep (see the module docstring)."""
    csv_path = sweep_dir / "commands.csv"
    if not csv_path.is_file():
        raise InputError("sweep file not found (expected commands.csv)", file=csv_path)
    frames, commands = [], []
    try:
        text = csv_path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read file: {exc}", file=csv_path) from None
    reader = csv.reader(text.splitlines())
    header = next(reader, None)
    if header is None or [h.strip() for h in header] != SWEEP_HEADER:
        raise InputError(f"header must be '{','.join(SWEEP_HEADER)}'", file=csv_path, line=1)
    for line, row in enumerate(reader, start=2):
        if not row:
            continue
        if len(row) != 2:
            raise InputError("expected 2 fields", file=csv_path, line=line)
        try:
            value = float(row[1])
        except ValueError:
            raise InputError(
                f"not a number: {row[1]!r}", file=csv_path, line=line, field="command_v"
            ) from None
        if not np.isfinite(value):
            raise InputError("not finite", file=csv_path, line=line, field="command_v")
        frames.append(read_image(sweep_dir / row[0].strip()))
        commands.append(value)
    if not frames:
        raise InputError("no frames listed", file=csv_path)
    return frames, np.array(commands)


def _load_model(path: Path | None) -> SensorModel:
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
    model = _load_model(args.sensor)
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


def _parse_pattern(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--pattern must be COLSxROWS, got {text!r}") from None
    if cols < 3 or rows < 3:
        raise InputError("--pattern needs at least 3x3 inner corners")
    return cols, rows


def run_calibrate(args: argparse.Namespace) -> int:
    """Calibrate from CALIB_DIR and write the sensor TOML."""
    check_output(args.out)
    board = Chessboard(pattern=_parse_pattern(args.pattern), square_mm=args.square_mm)
    board_dir, target_dir = args.dir / "chessboards", args.dir / "targets"
    if not board_dir.is_dir() or not target_dir.is_dir():
        raise InputError("expected sub-folders chessboards/ and targets/", file=args.dir)
    boards = [read_image(p) for p in sorted(board_dir.glob("*.png"))]
    targets, commands = [], None
    for pose_dir in sorted(p for p in target_dir.iterdir() if p.is_dir()):
        frames, cmds = read_sweep(pose_dir)
        if commands is not None and not np.array_equal(cmds, commands):
            raise InputError(
                "all target sweeps must use the same commands", file=pose_dir / "commands.csv"
            )
        commands = cmds
        targets.append((read_image(pose_dir / "board.png"), frames))
    if commands is None:
        raise InputError("no target poses found", file=target_dir)
    try:
        model = calibrate_sensor(
            boards,
            targets,
            commands,
            board=board,
            mode=args.mode,
            name=f"calibrated from {args.dir.name}",
        )
    except CalibrationFailed as exc:
        raise InputError(f"calibration failed: {exc}", file=args.dir) from exc
    write_text(args.out, dumps_sensor_model(model))
    K = model.camera.K
    print(
        f"wrote {args.out}: fx {K[0, 0]:.2f} px, fy {K[1, 1]:.2f} px, reprojection "
        f"{model.camera.rms_reprojection_px:.3f} px, laser plane rms "
        f"{model.laser.rms_plane_mm:.4f} mm"
    )
    return 0
