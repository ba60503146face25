"""Recorded sensor data on disk (PNG frames, 8 or 16 bit; commands in volts) and the sensor
calibration from it: what `rvis sensor` reads and `rvis commission` captures and reads.

    SWEEP_DIR/commands.csv        header `frame,command_v`; one row per frame: PNG file name
                                  (relative to SWEEP_DIR) and the galvo command it was taken at
    CALIB_DIR/chessboards/*.png   chessboard views for the intrinsics
    CALIB_DIR/targets/<pose>/board.png      the flat target's chessboard at that pose
    CALIB_DIR/targets/<pose>/commands.csv   a sweep over the target's white face (as above)
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.files import write_bytes, write_csv
from vision.calibrate import Chessboard
from vision.calibrate_sensor import calibrate_sensor
from vision.errors import CalibrationFailed
from vision.sensor_model import SensorModel

SWEEP_HEADER = ["frame", "command_v"]


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


def write_image(path: Path, image: NDArray[np.generic]) -> None:
    """A grey frame (uint8 or uint16) as a PNG, written atomically."""
    ok, data = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise InputError("cannot encode the frame as PNG", file=path)
    write_bytes(path, data.tobytes())


def write_sweep(
    sweep_dir: Path, frames: Sequence[NDArray[np.generic]], commands_v: Sequence[float]
) -> None:
    """A sweep in the SWEEP_DIR layout (frame_NN.png and commands.csv)."""
    rows = []
    for k, (frame, v) in enumerate(zip(frames, commands_v, strict=True)):
        name = f"frame_{k:02d}.png"
        write_image(sweep_dir / name, frame)
        rows.append([name, float(v)])
    write_csv(sweep_dir / "commands.csv", SWEEP_HEADER, rows)


def _parse_pattern(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--pattern must be COLSxROWS, got {text!r}") from None
    if cols < 3 or rows < 3:
        raise InputError("--pattern needs at least 3x3 inner corners")
    return cols, rows


def calibrate_dir(
    calib_dir: Path, pattern: str = "9x6", square_mm: float = 2.5, mode: str = "fast"
) -> SensorModel:
    """The sensor calibrated from CALIB_DIR (layout above); InputError naming the folder when
    the data do not determine it."""
    board = Chessboard(pattern=_parse_pattern(pattern), square_mm=square_mm)
    board_dir, target_dir = calib_dir / "chessboards", calib_dir / "targets"
    if not board_dir.is_dir() or not target_dir.is_dir():
        raise InputError("expected sub-folders chessboards/ and targets/", file=calib_dir)
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
        return calibrate_sensor(
            boards,
            targets,
            commands,
            board=board,
            mode=mode,
            name=f"calibrated from {calib_dir.name}",
        )
    except CalibrationFailed as exc:
        raise InputError(f"calibration failed: {exc}", file=calib_dir) from exc
