"""The sphere scene (the laser-independent part of rendering) reused across frames: the same
frames as rendering from scratch, and the camera of the simulated line reuses it only while
the sphere stands still."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from app.config import CellConfig
from fakes.cell import SimulatedCell
from fakes.render import render_sphere_sweep, sphere_scene
from fakes.render_sensor import TrueSensor

ViewOf = Callable[[SimulatedCell, str], np.ndarray]  # the view_of fixture (conftest)


def test_a_reused_scene_renders_the_same_frames(true_sensor: TrueSensor) -> None:
    c = np.array([3.0, -2.0, 131.0])
    commands = np.linspace(-1.0, 1.0, 4)
    scene = sphere_scene(true_sensor, c, 15.0)
    fresh = render_sphere_sweep(c, 15.0, true_sensor, np.random.default_rng(2), commands_v=commands)
    reused = render_sphere_sweep(
        c, 15.0, true_sensor, np.random.default_rng(2), commands_v=commands, scene=scene
    )
    assert int(fresh[0].max()) > 100
    np.testing.assert_array_equal(fresh[0], reused[0])
    with pytest.raises(ValueError, match="another sphere"):
        render_sphere_sweep(c + 0.01, 15.0, true_sensor, np.random.default_rng(2), scene=scene)


def test_the_camera_reuses_the_scene_only_while_the_sphere_stands_still(
    cfg: CellConfig, line_cell: SimulatedCell, view_of: ViewOf
) -> None:
    q = view_of(line_cell, "P1")
    line_cell.set_joints_deg(q)
    line_cell.render_frame_v(1296, 966, 10_000.0, 0.0, 0.0)
    first = line_cell.frames.scene
    line_cell.render_frame_v(1296, 966, 10_000.0, 0.0, 0.3)
    assert line_cell.frames.scene is first and first is not None
    # where the robot stands: the commanded joints plus this stop's repeatability error
    truth = line_cell.centre_in_sensor(line_cell.attained_deg(), cfg.spheres_part_mm["P1"])[0]
    np.testing.assert_allclose(first.c_sensor_mm, truth, atol=1e-4)
    line_cell.set_joints_deg(q + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.01]))  # J6: 0.01 deg
    line_cell.render_frame_v(1296, 966, 10_000.0, 0.0, 0.0)
    assert line_cell.frames.scene is not first
