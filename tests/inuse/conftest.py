"""A calibration of the simulated cell (seeded, once per session): the cell knows the true
robot, the parameters file is what `rvis identify` would write."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from app.config import load_cell
from app.formats.files import write_json
from app.formats.params import to_json
from app.sim.cell import collect, make_cell
from app.sim.compensation import view_configurations
from calib.identify import identify
from calib.model import SystemModel
from fakes.cell import SimulatedCell

F64 = np.ndarray


@dataclass(frozen=True)
class Calibrated:
    cell: SimulatedCell
    model: SystemModel
    x: F64
    params: Path
    views_deg: F64  # 40 inspection views (joint targets on the nominal model)


@pytest.fixture(scope="session")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Calibrated:
    cfg = load_cell(None)
    cell = make_cell(cfg, seed=3)
    model = cfg.model()
    rng = np.random.default_rng([3, 2])
    data = collect(cell, model, model.nominal_x(), cfg.spheres_part_mm, 6, rng)
    result = identify(model, data.measurements)
    path = tmp_path_factory.mktemp("cal") / "params.json"
    write_json(path, to_json(model, result))
    views = view_configurations(cfg, 40, np.random.default_rng(7))
    return Calibrated(cell, model, result.x, path, views)


def standoff_error_mm(cell: SimulatedCell, q_deg: F64, T_intended: F64) -> F64:
    """Distance between where the true robot puts the sensor's standoff point (130 mm along
    its axis) and where the intended pose has it."""
    c = np.array([0.0, 0.0, 130.0, 1.0])
    true = cell.T_part_sensor(q_deg) @ c
    out: F64 = np.linalg.norm((true - T_intended @ c)[:, :3], axis=1)
    return out
