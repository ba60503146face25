"""The cold cell's offline calibration on the simulated line: the simulated commissioning
(`commissioned`: random views a sphere and the workspace validation's errors, measured as the
line measures them) and the random schedule a run without a plan file measures."""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from app.config import CellConfig
from app.sim.cell import DataSet, simulated_sets
from app.sim.truth import EndToEndTruth
from calib import candidates
from calib.identify import IdentificationResult, Measurements, identify
from fakes.cell import SimulatedCell

F64 = NDArray[np.float64]


def as_the_line_measures(data_set: DataSet, truth: EndToEndTruth | None) -> Measurements:
    """A simulated data set's measurements as the line measures them: with `truth`, each view
    through its sensor model (the centre it reports plus the sensor noise; views its vision
    checks reject left out); without, the geometric path's."""
    data = data_set.measurements
    if truth is None or truth.kinematic_only:
        return data
    c_true = data_set.truth_c_sensor_mm
    c_seen, ok = truth.centres(c_true)
    keep = np.flatnonzero(ok)  # a rejected view reports no centre (NaN): left out first
    data = data.subset(keep)
    return dataclasses.replace(data, c_sensor_mm=data.c_sensor_mm + (c_seen - c_true)[keep])


def commissioning(
    cfg: CellConfig, seed: int, truth: EndToEndTruth | None = None
) -> IdentificationResult:
    """The offline calibration of the cold cell (`commissioned`)."""
    return commissioned(cfg, seed, truth)[0]


def commissioned(
    cfg: CellConfig, seed: int, truth: EndToEndTruth | None = None
) -> tuple[IdentificationResult, F64]:
    """The offline calibration of the cold cell (4 spheres x `[commission]
    calibration_views_per_sphere` random views) with the commissioning's model
    (CellConfig.commissioning_model; the cold cell's temperature with every view), and the errors'
    norms (n,) [mm] its workspace validation measures: the validation sphere at `[commission]
    workspace_positions` random positions no calibration view used, each tracked (with the
    tracker's noise) and measured from one view (app/commission/workspace.py measures the same
    on the devices). With `truth`, each view is measured through its sensor model (the centre
    it reports plus the sensor noise; views its vision checks reject left out), as the line
    will measure. One simulation of the cell for both."""
    sim = simulated_sets(
        cfg,
        seed,
        n_each=max(cfg.commission.calibration_views_per_sphere, cfg.calibration.configs_per_sphere),
        n_validation=cfg.commission.workspace_positions,
    )
    model = cfg.commissioning_model()
    data = _cold(as_the_line_measures(sim.calibration, truth), sim.cell.temp_c)
    result = identify(model, data)
    val = _cold(as_the_line_measures(sim.validation, truth), sim.cell.temp_c)
    p = model.points_part(result.x, val.q_deg, val.c_sensor_mm, temp_c=val.temp_c)
    norms: F64 = np.linalg.norm(p - val.p_part_mm, axis=1)
    return result, norms


def _cold(data: Measurements, temp_c: float) -> Measurements:
    """`data` with the cold cell's temperature at every view that carries none."""
    if data.temp_c is not None:
        return data
    return dataclasses.replace(data, temp_c=np.full(len(data), temp_c))


def random_schedule(cfg: CellConfig, cell: SimulatedCell, seed: int, n_each: int) -> dict[str, F64]:
    """n_each random views per sphere that the nominal model plans and the cell sees (the
    schedule when no plan file is given)."""
    model = cfg.model()
    x0 = model.nominal_x()
    rng = np.random.default_rng([seed, 9])
    out = {}
    for tid, p in cfg.spheres_part_mm.items():
        q = candidates.random_configurations(model, x0, p, 4 * n_each, rng).q_deg
        out[tid] = q[cell.sees_each(q, p)][:n_each]
    return out
