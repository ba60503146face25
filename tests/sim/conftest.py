"""Fixtures for the simulated line: the true sensor built once per session (its pixel rays take
seconds), cells built from the default configuration, a view of a sphere, and the drivers' leak
check (a test that leaves a device open fails)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from app.config import CellConfig
from app.sim.cell import make_cell
from calib import candidates
from drivers.base import open_devices
from fakes.cell import SimulatedCell
from fakes.render_sensor import TrueSensor, default_true_sensor


@pytest.fixture(autouse=True)
def _no_device_left_open() -> Iterator[None]:
    before = set(map(id, open_devices()))
    yield
    leaked = [d for d in open_devices() if id(d) not in before]
    for device in leaked:
        device.close()
    assert not leaked, f"test left devices open: {[d.name for d in leaked]}"


@pytest.fixture(scope="session")
def true_sensor() -> TrueSensor:
    sensor = default_true_sensor()
    _ = sensor.pixel_rays
    return sensor


@pytest.fixture()
def line_cell(cfg: CellConfig, true_sensor: TrueSensor) -> SimulatedCell:
    """A fresh simulated cell (seed 11) sharing the session's true sensor."""
    return make_cell(cfg, seed=11, sensor=true_sensor)


ViewOf = Callable[[SimulatedCell, str], np.ndarray]


@pytest.fixture()
def view_of(cfg: CellConfig) -> ViewOf:
    """view_of(cell, target): a configuration (controller angles [deg]) from which the cell sees
    the sphere near the middle of the field of view."""

    def central_view(cell: SimulatedCell, target: str) -> np.ndarray:
        model = cfg.model()
        p = cfg.spheres_part_mm[target]
        qs = candidates.random_configurations(
            model, model.nominal_x(), p, 60, np.random.default_rng(1)
        ).q_deg
        c = cell.centre_in_sensor(qs, p, 0.0)
        lateral = np.where(cell.spec.volume.contains(c), np.hypot(c[:, 0], c[:, 1]), np.inf)
        best = int(np.argmin(lateral))
        assert lateral[best] < 6.0
        return np.asarray(qs[best])

    return central_view
