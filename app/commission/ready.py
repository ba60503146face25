"""The last step: the state directory made ready for `rvis run`, and checked by reading it back
the way the service will.

    plan.json      the commissioning's plan (the service's schedule)
    cell.toml      the cell file with the tracker's sphere positions and the chosen exposure
    sensor.toml    the sensor calibration (`rvis run` reads it when --sensor is not given)
    params/        the calibration as version 1 of params/current.json and params/history/,
    rvis.db        and the database's record of it, as the service writes its first version

Run again (killed after the files, before the journal), it finds its own version 1 and goes on;
a directory holding any other calibration is refused.
"""

from __future__ import annotations

import dataclasses
import shlex

import numpy as np

from app.commission.checks import Check, StepResult, holds
from app.commission.context import Context
from app.commission.files import (
    PARAMS_FILE,
    PLAN_FILE,
    SENSOR_FILE,
    STRIPE_FILE,
    WORKSPACE_ERRORS_FILE,
)
from app.commission.workspace import workspace_evidence_mm
from app.config import CellConfig, load_cell
from app.config.devices import CameraSection
from app.config.write import dumps_cell
from app.formats.files import read_json, write_bytes, write_text
from app.formats.params import from_json
from app.line.params_store import ParamsStore, first_in_force
from app.line.schedule import Schedule
from app.line.store import Store
from calib.uncertainty import accuracy_limit_mm, u95_mm


def ready(ctx: Context) -> StepResult:
    state, r = ctx.state, StepResult()
    write_bytes(state.plan, ctx.path(PLAN_FILE).read_bytes())
    write_bytes(state.sensor, ctx.path(SENSOR_FILE).read_bytes())
    cell = _commissioned_cell(ctx)
    write_text(state.cell, dumps_cell(cell, f"written by rvis commission from {ctx.cfg.source}"))
    version = _apply_once(ctx)
    r.results["version"] = version
    # the limit the service holds the cell's U95 to, as written into cell.toml
    r.results["accuracy_limit_mm"] = cell.service.accuracy_limit_mm
    # `rvis run --state-dir S` reads S/cell.toml, S/plan.json and S/sensor.toml
    r.results["run"] = f"rvis run --state-dir {shlex.quote(str(state.root))}"
    if ctx.truth is not None:  # the simulated line: its own devices, the same cell (seed)
        geometric = " --geometric" if ctx.truth.geometric else ""  # measured as commissioned
        r.results["run"] = (
            f"rvis run --sim{geometric} --seed {ctx.truth.seed}"
            f" --state-dir {shlex.quote(str(state.root))}"
        )
    r.checks += _read_back(ctx, cell)
    return r


def _commissioned_cell(ctx: Context) -> CellConfig:
    """The cell with the measured spheres, this state directory, on the simulated line its
    seed and measuring path (and the rendered sensor's edge allowances, `[sensor] edge_u_mm`
    and `edge_u_slot_mm`, as bench/edge.py measured them on certified bores and slots, where
    larger than the cell file's), and, when the stripe step chose one, its exposure."""
    cell = ctx.cell()
    service = dataclasses.replace(cell.service, state_dir=str(ctx.state.root.resolve()))
    tolerance = ctx.cfg.commission.tolerance_mm
    errors = workspace_evidence_mm(ctx.path(WORKSPACE_ERRORS_FILE))
    if tolerance > 0 or errors:  # the limit of the U95 the service vouches for (VDA 5 and the
        # cell's own U95: calib.uncertainty.accuracy_limit_mm)
        own = u95_mm(errors) if errors else None
        limit = accuracy_limit_mm(tolerance, own)[0]
        service = dataclasses.replace(service, accuracy_limit_mm=limit)
    cell = dataclasses.replace(cell, service=service)
    if ctx.truth is not None:  # the simulated cell: its seed and path, for `run --sim` later
        simulation = dataclasses.replace(
            cell.simulation, seed=ctx.truth.seed, geometric=ctx.truth.geometric
        )
        cell = dataclasses.replace(cell, simulation=simulation)
        edge = ctx.truth.sensor_edge_u_mm  # the simulated sensor's, from certified bores
        if edge is not None:
            sensor = dataclasses.replace(
                cell.sensor,
                edge_u_mm=max(cell.sensor.edge_u_mm, edge["hole"]),
                edge_u_slot_mm=max(cell.sensor.edge_u_slot_mm, edge["slot"]),
            )
            cell = dataclasses.replace(cell, sensor=sensor)
    stripe = ctx.path(STRIPE_FILE)
    if stripe.exists():
        exposure = float(read_json(stripe)["chosen"]["exposure_us"])
        cell = dataclasses.replace(cell, camera=CameraSection(exposure, cell.camera.gain_db))
    return cell


def _apply_once(ctx: Context) -> int:
    """The commissioning's parameters as version 1, exactly once (see the module docstring),
    by the service's rule for a first version (`first_in_force`) at the context's clock."""
    doc = read_json(ctx.path(PARAMS_FILE))
    params = ParamsStore(ctx.state.root)
    store = Store(ctx.state.db)
    try:
        current = params.current()
        if current is not None:  # an earlier run wrote it: ours, or another calibration
            version, _, x = current
            _, x_ours = from_json(ctx.path(PARAMS_FILE))
            if version != 1 or x.shape != x_ours.shape or not np.allclose(x, x_ours):
                raise RuntimeError(f"{ctx.state.current} holds another calibration")
        doc = {**doc, "source": "commissioning"}
        errors = workspace_evidence_mm(ctx.path(WORKSPACE_ERRORS_FILE))
        if errors:  # the version's prediction error across the workspace: the service's U95
            doc["validation"] = {"errors_mm": errors, "what": "commissioning workspace step"}
        written = None if current is None else current[0]
        return first_in_force(params, store, doc, "commissioning", ctx.clock, written)
    finally:
        store.close()


def _read_back(ctx: Context, cell: CellConfig) -> list[Check]:
    state = ctx.state
    loaded = load_cell(state.cell)
    schedule = Schedule.from_plan(state.plan, ctx.line)
    _, x_ours = from_json(ctx.path(PARAMS_FILE))
    current = ParamsStore(state.root).current()
    store = Store(state.db, read_only=True)
    try:
        applied = store.applied()
    finally:
        store.close()
    same_spheres = set(loaded.spheres_part_mm) == set(ctx.spheres_part_mm()) and all(
        np.allclose(loaded.spheres_part_mm[k], v, atol=1e-6)
        for k, v in ctx.spheres_part_mm().items()
    )
    same_spheres &= loaded.camera == cell.camera
    n = len(schedule)
    return [
        holds("cell.toml reads back (spheres, exposure)", same_spheres),
        holds("plan.json reads as the service's schedule", n > 0, f"{n} slots"),
        holds(
            "params/current.json is the calibration (version 1)",
            current is not None and current[0] == 1 and np.allclose(current[2], x_ours),
        ),
        holds("rvis.db records version 1", [a["version"] for a in applied] == [1]),
    ]
