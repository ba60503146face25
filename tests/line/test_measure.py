"""The measurement of one sphere through the drivers: the fake robot moves the simulated cell,
the galvo sweeps in volts, the fake camera renders each frame, vision measures the centre; the
cell knows the true centre. Also the geometric seam, a rejected sweep and the way home."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from app.config import load_cell
from app.config.line import LineSettings, SweepSettings
from app.line.measure import GeometricSensor, Rejected, SphereMeasurer, SweepSensor
from app.sim.cell import make_cell
from fakes.cell import SimulatedCell
from fakes.devices import FakeCamera, FakeGalvo, FakeRobot
from tests.line.helpers import plan_for
from vision.sensor_model import default_sensor_model

SEED = 3


@pytest.fixture(scope="module")
def cell() -> SimulatedCell:
    return make_cell(load_cell(None), SEED)


@pytest.fixture()
def rig(cell: SimulatedCell) -> Iterator[tuple[FakeRobot, FakeGalvo, FakeCamera]]:
    robot = FakeRobot(cell, time_scale=0.001).open()
    galvo = FakeGalvo().open()
    camera = FakeCamera(cell, galvo=galvo)
    camera.open()
    cell.set_joints_deg(LineSettings().home_deg)
    yield robot, galvo, camera
    for d in (camera, galvo, robot):
        d.close()


def test_sweep_sensor_measures_the_true_centre(
    cell: SimulatedCell, rig: tuple[FakeRobot, FakeGalvo, FakeCamera]
) -> None:
    robot, galvo, camera = rig
    sensor = SweepSensor(camera, galvo, default_sensor_model(), SweepSettings(), keep_frames=True)
    measurer = SphereMeasurer(robot, sensor, LineSettings())
    q = plan_for(SEED)["P2"][0]
    reading = measurer.measure_one(q, "P2")
    truth = cell.centre_in_sensor(q[None], cell.target_true_mm("P2"))[0]
    assert np.linalg.norm(reading.c_sensor_mm - truth) < 0.1
    assert reading.frames is not None and reading.frames.shape[0] == 24
    assert reading.quality["n_frames_used"] >= 5
    assert galvo.output_v == 0.0  # parked after the sweep
    assert measurer.at_home()


def test_a_sweep_without_a_sphere_is_rejected_and_the_robot_comes_home(
    rig: tuple[FakeRobot, FakeGalvo, FakeCamera],
) -> None:
    robot, galvo, camera = rig
    sensor = SweepSensor(camera, galvo, default_sensor_model(), SweepSettings(n_frames=4))
    measurer = SphereMeasurer(robot, sensor, LineSettings())
    q_nothing = np.array([0.0, 10.0, 0.0, 0.0, -90.0, 0.0])  # looking at no sphere
    with pytest.raises(Rejected, match=r"NoStripe|TooFewPoints|SphereFit"):
        measurer.measure_one(q_nothing, "P1")
    assert measurer.at_home()


def test_geometric_sensor_reads_the_callable_at_the_robot_pose(cell: SimulatedCell) -> None:
    robot = FakeRobot(cell, time_scale=0.001).open()
    try:
        measurer = SphereMeasurer(robot, GeometricSensor(cell.measure_target), LineSettings())
        q = plan_for(SEED)["P3"][1]
        measurer.move_to(q)
        reading = measurer.sensor.measure("P3")
        truth = cell.centre_in_sensor(q[None], cell.target_true_mm("P3"))[0]
        assert np.linalg.norm(reading.c_sensor_mm - truth) < 0.1  # cell noise 0.02 mm
        measurer.go_home()
        assert measurer.at_home()
    finally:
        robot.close()
