"""Shared fixtures: the default cell and simulated data sets (seeded, cached per session)."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as app/__init__.py; before numpy loads

from functools import cache

import numpy as np
import pytest

from app.config import CellConfig, load_cell
from app.simulation import DataSet, collect, make_cell, validation_set


@pytest.fixture(scope="session")
def cfg() -> CellConfig:
    return load_cell(None)


@cache
def simulated(seed: int, n_validation: int = 60, **overrides: object) -> tuple[DataSet, DataSet]:
    """(calibration set of 4 x 6, validation set) of the simulated cell."""
    cfg = load_cell(None)
    cell = make_cell(cfg, seed=seed, **overrides)
    model = cfg.model()
    rng = np.random.default_rng([seed, 2])
    x0 = model.nominal_x()
    cal = collect(cell, model, x0, cfg.spheres_part_mm, 6, rng)
    val = validation_set(cell, cfg, model, x0, n_validation, rng)
    return cal, val
