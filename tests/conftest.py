"""Shared fixtures: the default cell and simulated data sets (seeded, cached per session)."""

from __future__ import annotations

from app.threads import limit_blas_threads

limit_blas_threads()  # as the rvis entry point does, before numpy loads

from functools import cache  # noqa: E402

import pytest  # noqa: E402

from app.config import CellConfig, load_cell  # noqa: E402
from app.sim.cell import DataSet, simulated_sets  # noqa: E402
from fakes.wiring import register_fakes  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _fakes_wired() -> None:
    """fake:// opens the simulated cell's devices, as the application wires them."""
    register_fakes()


@pytest.fixture(scope="session")
def cfg() -> CellConfig:
    return load_cell(None)


@cache
def simulated(seed: int, n_validation: int = 60, **overrides: bool) -> tuple[DataSet, DataSet]:
    """(calibration set of 4 x 6, validation set) of the simulated cell."""
    sim = simulated_sets(load_cell(None), seed, n_each=6, n_validation=n_validation, **overrides)  # type: ignore[arg-type]
    return sim.calibration, sim.validation
