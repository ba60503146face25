"""Shared fixtures: the simulated sensor's truth (its pixel rays take ~1 s, built once)."""

from __future__ import annotations

import numpy as np
import pytest

from app.sim.cell import true_sensor_model
from fakes.render_sensor import TrueSensor, default_true_sensor
from vision.sensor_model import SensorModel


@pytest.fixture(scope="session")
def true_sensor() -> TrueSensor:
    sensor = default_true_sensor()
    _ = sensor.pixel_rays
    return sensor


@pytest.fixture(scope="session")
def perfect_model(true_sensor: TrueSensor) -> SensorModel:
    return true_sensor_model(true_sensor)


@pytest.fixture()
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)
