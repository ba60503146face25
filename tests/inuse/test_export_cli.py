"""`rvis export urdf` on a calibration of the simulated cell: an independent URDF library
(yourdfpy) reads it, its FK is the identified model's, and it lands near the true robot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from app.commands.cli import main
from calib.urdf import urdf_angles
from tests.inuse.conftest import Calibrated


def test_exported_urdf_is_the_identified_robot(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cell" / "robot.urdf"
    assert main(["export", "urdf", "--params", str(calibrated.params), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    robot = yourdfpy.URDF.load(str(out), load_meshes=False)
    assert robot.validate()
    assert {"part", "base_link", "base", "link_6", "tool0", "sensor"} <= set(robot.link_map)
    q = calibrated.views_deg
    T_model = calibrated.model.fk(calibrated.x, q)
    T_true = calibrated.cell.T_part_sensor(q)
    standoff = np.array([0.0, 0.0, 130.0, 1.0])
    worst_model, worst_true = 0.0, 0.0
    for i in range(len(q)):
        robot.update_cfg(urdf_angles(q[i]))
        T = np.array(robot.get_transform("sensor", "part"))
        T[:3, 3] *= 1000.0
        worst_model = max(worst_model, float(np.abs(T - T_model[i]).max()))
        worst_true = max(worst_true, float(np.linalg.norm((T - T_true[i]) @ standoff)))
    assert worst_model < 1e-6
    assert worst_true < 0.2  # the identified robot, not the nominal one: at the calibrated level
