"""Poses and image sets of the sensor-calibration targets, rendered with known truth.

Used by tests, bench/vision.py and `rvis demo` to produce what an operator records on the line:
chessboard views for the intrinsics, and per flat-target pose a chessboard image plus a laser
sweep over the target's white face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from fakes.render import Frames, default_sweep_commands
from fakes.render_plane import render_chessboard, render_plane_sweep
from fakes.render_sensor import TrueSensor

F64 = NDArray[np.float64]
BOARD_CENTRE_MM = np.array([10.0, 6.25, 0.0])  # centre of the default 9x6, 2.5 mm board


def board_pose(centre_mm: F64, rotvec_deg: F64) -> F64:
    """T_camera_target putting the board centre at centre_mm [camera frame], rotated."""
    T = np.eye(4)
    R = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre_mm) - R @ BOARD_CENTRE_MM
    return T


@dataclass(frozen=True, eq=False)
class CalibrationSet:
    """chessboards: views for the intrinsics; targets: per pose (chessboard image, sweep frames);
    commands_v: the sweep commands shared by all target poses; poses: the true T_camera_target."""

    chessboards: list[Frames]
    targets: list[tuple[Frames, Frames]]
    commands_v: F64
    chessboard_poses: list[F64]
    target_poses: list[F64]


def render_calibration_set(
    sensor: TrueSensor,
    rng: np.random.Generator,
    *,
    n_chessboards: int = 12,
    n_targets: int = 4,
    n_commands: int = 15,
) -> CalibrationSet:
    """Chessboards at 115-132 mm tilted up to 25 deg; flat targets at 118-134 mm tilted 10-15
    deg about alternating axes (never parallel), each swept with the same commands."""
    boards, board_poses = [], []
    for _ in range(n_chessboards):
        rv = np.array([rng.uniform(-25, 25), rng.uniform(-25, 25), rng.uniform(-10, 10)])
        centre = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(115, 132)])
        T = board_pose(centre, rv)
        boards.append(render_chessboard(T, sensor, rng)[0])
        board_poses.append(T)
    cmds = default_sweep_commands(n_commands, 3.4)
    targets, target_poses = [], []
    signs = [(1, -1), (-1, 1), (1, 1), (-1, -1)]
    for k, z in enumerate(np.linspace(118.0, 134.0, n_targets)):
        sx, sy = signs[k % 4]
        T = board_pose(np.array([0.0, 0.0, z]), np.array([sx * 14.0, sy * 12.0, 0.0]))
        frames, _, _ = render_plane_sweep(T, sensor, rng, commands_v=cmds)
        targets.append((render_chessboard(T, sensor, rng)[0], frames))
        target_poses.append(T)
    return CalibrationSet(
        chessboards=boards,
        targets=targets,
        commands_v=cmds,
        chessboard_poses=board_poses,
        target_poses=target_poses,
    )
