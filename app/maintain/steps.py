"""The maintenance procedures' own first steps (app/maintain/__init__.py): what the state
directory holds now and the axis's zero found. The changed group identified on the spheres is
app/maintain/reidentify.py, the workspace validation app/maintain/workspace.py, the fixture's
spheres app/maintain/fixture.py and the hand-over to `rvis run` app/maintain/handover.py. The
steps they share with the commissioning (the devices' answers, the sensor calibration, the
tracker's spheres, the acceptance) are the commissioning's, run in the procedure's folder on
the files `prepare` puts there (the same names: app/commission/files.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.checks import StepResult, at_most, holds
from app.commission.context import Context
from app.commission.files import (
    PARAMS_BEFORE_FILE,
    PARAMS_FILE,
    PLAN_FILE,
    SENSOR_FILE,
    TARGETS_BEFORE_FILE,
    TARGETS_FILE,
)
from app.commission.steps import device_checks
from app.formats.files import read_json, write_bytes, write_json, write_targets
from app.formats.params import from_json
from app.line.measure import Rejected
from app.line.params_store import ParamsStore
from app.maintain.aim import zero_moved, zero_of
from app.maintain.context import MaintenanceContext
from app.maintain.views import Views, aimed

F64 = NDArray[np.float64]

#: the search for an axis's zero where no sphere is seen: steps [deg] up to the limit
ZERO_STEP_DEG = 0.2
ZERO_LIMIT_DEG = 1.4


# -- devices and what the state directory holds ----------------------------------------------
def devices(ctx: Context) -> StepResult:
    """Every device answers, the robot at home without an alarm, the PLC alive, and the state
    directory commissioned (a version in force)."""
    r = device_checks(ctx)
    current = ParamsStore(ctx.state.root).current_version()
    r.checks.append(
        holds("a commissioned state directory", current is not None, str(ctx.state.root))
    )
    return r


def prepare(ctx: Context) -> StepResult:
    """The version in force, the plan, the sensor calibration and the spheres' places copied
    into the procedure's folder (the steps after work on them there; the state directory is
    changed only by the hand-over)."""
    state, r = ctx.state, StepResult()
    params = ParamsStore(state.root)
    version, doc = params.current_version(), params.current_document()
    if version is None or doc is None:
        r.checks.append(holds("a version in force", False, str(params.current_path)))
        return r
    write_json(ctx.path(PARAMS_BEFORE_FILE), doc)
    write_json(ctx.path(PARAMS_FILE), doc)
    write_bytes(ctx.path(PLAN_FILE), state.plan.read_bytes())
    write_bytes(ctx.path(SENSOR_FILE), state.sensor.read_bytes())
    spheres = dict(ctx.cfg.spheres_part_mm)
    write_targets(ctx.path(TARGETS_BEFORE_FILE), spheres)
    write_targets(ctx.path(TARGETS_FILE), spheres)
    errors = (doc.get("validation") or {}).get("errors_mm") or []
    r.results = {"version": version, "spheres": len(spheres)}
    if errors:
        r.results["validation_rmse_mm"] = float(np.sqrt(np.mean(np.square(errors))))
    r.files += [PARAMS_BEFORE_FILE, PARAMS_FILE, PLAN_FILE, SENSOR_FILE, TARGETS_BEFORE_FILE]
    r.checks.append(holds("a version in force", True, f"version {version}"))
    return r


# -- axis N: the zero -----------------------------------------------------------------------------
def zero(ctx: Context) -> StepResult:
    """The axis's zero, found from one view of the plan: measured as it is; where its sphere is
    not seen, the view re-aimed on the zero moved by +-0.2, +-0.4, ... deg until it is; the
    zero then solved from that measurement (the rest held). Writes the parameters with it."""
    m = MaintenanceContext.of(ctx)
    assert m.axis is not None
    model, x_before = from_json(ctx.path(PARAMS_BEFORE_FILE))
    views = Views.of_plan(ctx)
    sensor = ctx.sphere_sensor(ctx.sensor_model())
    r = StepResult()
    tried: list[float] = []
    first = 0
    ctx.home()
    for delta in _search_deltas():
        x_try = zero_moved(x_before, m.axis, delta)
        q, ok = aimed(ctx, views.pick([first]), x_try)
        if not ok[0]:
            continue
        tried.append(delta)
        ctx.move(q[0], f"the zero's search: {delta:+.1f} deg on J{m.axis}")
        ctx.robot_s += ctx.sweep.duration_s
        try:
            reading = sensor.measure(views.targets[first])
        except Rejected:
            ctx.say(f"    {delta:+.1f} deg: no sphere seen")
            continue
        ctx.home()
        found = _solve_zero(ctx, model, x_try, q[0], reading.c_sensor_mm, views.targets[first])
        x_found = zero_moved(x_try, m.axis, found)
        doc = read_json(ctx.path(PARAMS_BEFORE_FILE))
        write_json(ctx.path(PARAMS_FILE), _with_x(doc, model, x_found, "zero search"))
        change = zero_of(x_found, x_before, m.axis)
        r.results = {"zero_change_deg": change, "tried_deg": tried}
        r.files.append(PARAMS_FILE)
        r.checks.append(
            holds(f"a sphere seen with J{m.axis}'s zero found", True, f"{change:+.3f} deg")
        )
        r.checks.append(at_most(f"J{m.axis} zero change", abs(change), ZERO_LIMIT_DEG + 0.1, "deg"))
        return r
    ctx.home()
    r.results = {"tried_deg": tried}
    r.checks.append(
        holds(f"a sphere seen within +-{ZERO_LIMIT_DEG:g} deg of J{m.axis}'s zero", False)
    )
    return r


def _search_deltas() -> list[float]:
    """0, then +-ZERO_STEP_DEG, +-2 ZERO_STEP_DEG, ... to ZERO_LIMIT_DEG."""
    n = round(ZERO_LIMIT_DEG / ZERO_STEP_DEG)
    out = [0.0]
    for k in range(1, n + 1):
        out += [k * ZERO_STEP_DEG, -k * ZERO_STEP_DEG]
    return out


def _solve_zero(ctx: Context, model: Any, x: F64, q_deg: F64, c_mm: F64, target: str) -> float:
    """The zero change [deg] on top of x that puts one measured centre on its sphere (least
    squares in one unknown, by Gauss-Newton on a numerical derivative)."""
    axis = MaintenanceContext.of(ctx).axis
    assert axis is not None
    p = ctx.spheres_part_mm()[target]

    def err(d: float) -> F64:
        point = model.points_part(zero_moved(x, axis, d), q_deg[None], c_mm[None])[0]
        out: F64 = point - p
        return out

    d = 0.0
    for _ in range(8):
        e, h = err(d), 1e-4
        g = (err(d + h) - e) / h
        step = -float(g @ e) / float(g @ g)
        d += step
        if abs(step) < 1e-7:
            break
    return d


def _with_x(doc: dict[str, Any], model: Any, x: F64, what: str) -> dict[str, Any]:
    """A parameters document of x (the version in force's `doc` with x in place)."""
    from app.formats.params import plain_document

    out = plain_document(model, x, f"rvis maintain ({what})")
    return {**out, "calibration_temp_c": doc.get("calibration_temp_c")}
