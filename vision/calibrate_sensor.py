"""The whole sensor calibration in one call: chessboards -> camera, target sweeps -> laser."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from vision.calibrate import (
    Chessboard,
    calibrate_camera,
    calibrate_laser,
    laser_points,
    target_plane,
)
from vision.sensor_model import SensorModel

Image = NDArray[np.generic]


def calibrate_sensor(
    chessboards: Sequence[Image],
    targets: Sequence[tuple[Image, Iterable[Image]]],
    commands_v: NDArray[np.float64],
    *,
    board: Chessboard | None = None,
    mode: str = "fast",
    name: str = "calibrated",
) -> SensorModel:
    """Calibrate the sensor.

    chessboards: images for the intrinsics; targets: per flat-target pose, its chessboard image
    and the sweep frames (one per command of commands_v [V]) over its white face.
    Raises CalibrationFailed when the data do not determine the model.
    """
    camera, _ = calibrate_camera(chessboards, board)
    points = []
    for board_image, frames in targets:
        plane = target_plane(board_image, camera, board)
        points.append(laser_points(frames, plane, camera, mode))
    laser = calibrate_laser(points, commands_v)
    return SensorModel(camera=camera, laser=laser, name=name)
