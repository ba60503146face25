"""The changed group identified on the spheres (a maintenance procedure's reidentify step,
app/maintain/__init__.py): the plan's views re-aimed, a subset chosen for the group, measured,
and the group identified with the rest held at the version in force."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.checks import StepResult, at_most, count_at_least, holds
from app.commission.context import Context
from app.commission.files import (
    MAINTENANCE_MEASUREMENTS_FILE,
    PARAMS_BEFORE_FILE,
    PARAMS_FILE,
    PLAN_FILE,
)
from app.commission.measuring import Taken, measure_views
from app.formats.files import read_json, write_json
from app.formats.params import from_json, to_json, with_held_covariance
from app.maintain.aim import zero_of
from app.maintain.context import MaintenanceContext
from app.maintain.views import Views, aimed, rigid_share
from app.meta import provenance
from app.motion import shortest_route
from calib import candidates
from calib.attribution import NONE, StepGroup, attribute
from calib.errors import InsufficientData, NotIdentifiable
from calib.gates import GateReport, check_identification
from calib.identify import IdentificationResult, Measurements, held_sensitivity, identify
from calib.model import BASE_NAMES, SENSOR_NAMES, unit_of
from calib.validation import rmse

F64 = NDArray[np.float64]


def reidentify(ctx: Context) -> StepResult:
    """The plan's views re-aimed on the parameters so far at the spheres' places now, measured
    from home and back, and the changed group identified with the rest held at the version in
    force: the sensor's 6 (sensor), the axis's zero (axis; J2's moves theta3 with it; J1's and
    J6's are the part frame's and the sensor's), the part frame (fixture) only if the
    measurements show it moved (BIC against nothing moved). Checked: views seen, residual RMS,
    condition, the change against the offline gates. Writes the parameters and the plan."""
    m = MaintenanceContext.of(ctx)
    cell = ctx.cell()
    model, x_start = from_json(ctx.path(PARAMS_FILE))
    _, x_before = from_json(ctx.path(PARAMS_BEFORE_FILE))
    views = Views.of_plan(ctx)
    q, ok = aimed(ctx, views, x_start)
    r = StepResult()
    limit = cell.commission.max_rejected_fraction
    n_all = len(ok)
    r.checks.append(count_at_least("views re-aimed", int(ok.sum()), n_all, n_all * (1 - limit)))
    sensor = ctx.sphere_sensor(ctx.sensor_model())
    rigid, xr = rigid_share(ctx, x_start)
    params = _group(m, model).params
    # a zero (one or two parameters) is settled by two views of each sphere, chosen among its
    # own (short moves); a 6-DoF group (sensor, part frame) by `[commission]
    # maintenance_views_per_sphere` times the spheres, chosen among all (its tilt and shift
    # are told apart by views far apart: measured, chosen per sphere the sensor's truth after
    # was 1.05-1.18x the unchanged cell's, among all 1.00-1.11x), a sensor's with views that
    # see the sphere elsewhere in the field of view (`_with_fov_views`)
    spheres = list(dict.fromkeys(views.targets))
    seen_ok = [k for k in range(len(ok)) if ok[k]]
    todo: list[int] = []
    if len(params) > 2:
        n = cell.commission.maintenance_views_per_sphere * len(spheres)
        todo = _subset(views, n, rigid, xr, params, among=seen_ok)
    else:
        for sphere in spheres:
            mine = [k for k in seen_ok if views.targets[k] == sphere]
            todo += _subset(views, 2, rigid, xr, params, seen=todo, among=mine)
    todo = sorted(todo)
    asked = len(todo)  # the plan's views the first look measures
    extra = 0  # a sensor's extra views beside them (`_with_fov_views`)
    taken = Taken()
    seen_at: list[int] = []
    x_new, result, group = x_start, None, _group(m, model)
    for attempt in range(2):  # a second look at the views not seen, re-aimed on the fit
        # in the order of least motion (the plan's order crosses the workspace)
        at = ctx.station.robot.joints_deg()
        order = shortest_route([q[k] for k in todo], at, ctx.line)
        chosen = [(views.targets[todo[j]], q[todo[j]]) for j in order]
        if attempt == 0 and m.event == "sensor":
            chosen = _with_fov_views(ctx, chosen, views, [todo[j] for j in order], rigid, xr)
        if attempt == 0:
            extra = len(chosen) - asked
        got = measure_views(ctx, chosen, sensor, "maintenance", via_home=False, end_home=False)
        seen_at += [k for k in todo if any(np.array_equal(q[k], v) for v in got.q_deg)]
        _extend(taken, got)
        data = taken.data(ctx.spheres_part_mm())
        try:
            if m.event == "fixture":
                group = _fixture_moved(model, x_start, data, cell)
            if group.params:
                result = identify(model, data, active=group.params, x0=x_start, align=False)
                x_new = result.x
        except (InsufficientData, NotIdentifiable) as exc:
            r.checks.append(holds("identification", False, str(exc)))
            return r
        if not got.rejected or attempt == 1:
            break
        # every view re-aimed on the fit, and as many as were missed chosen again among
        # those not seen yet (the missed ones included)
        missed = len([k for k in todo if k not in seen_at])
        q, ok = aimed(ctx, views, x_new)
        _, xr = rigid_share(ctx, x_new)
        pool = [k for k in range(len(ok)) if ok[k] and k not in seen_at]
        todo = _subset(views, missed, rigid, xr, params, seen=seen_at, among=pool)
    ctx.home()
    taken.write(ctx.path(MAINTENANCE_MEASUREMENTS_FILE))
    r.files.append(MAINTENANCE_MEASUREMENTS_FILE)
    # the plan's views seen of those the first look asked for (a second look measures at most
    # as many as the first missed, in their place): the gate; a sensor's extra views, aimed
    # at the field of view's edges on the mount before it was identified, are counted apart
    # and gate nothing (the fit's condition and gates judge what they added)
    seen = len(set(seen_at))
    r.checks.append(count_at_least("views seen", seen, asked, asked * (1 - limit)))
    r.results["views"] = {"asked": asked, "seen": seen, "rejected": len(taken.rejected)}
    if extra:
        r.results["views"] |= {"extra_asked": extra, "extra_seen": len(taken.targets) - seen}
    e = model.points_part(x_new, data.q_deg, data.c_sensor_mm, temp_c=data.temp_c)
    residual = rmse(e - data.p_part_mm)
    doc = read_json(ctx.path(PARAMS_BEFORE_FILE))
    if result is not None:
        report = check_identification(result, x_before, cell.calibration.gates())
        doc = group_document(model, data, result, report, ctx.path(PARAMS_BEFORE_FILE))
        condition = result.observability.condition
        r.checks.append(at_most("condition", condition, cell.calibration.max_condition))
        r.checks.append(holds("quality gates", report.passed, report.reason or "passed"))
        r.results["identified"] = list(group.params)
        r.results["standard_uncertainty"] = std_with_units(group.params, result.std)
    else:
        r.results["identified"] = []
    write_json(ctx.path(PARAMS_FILE), doc)
    r.files.append(PARAMS_FILE)
    r.checks.append(at_most("residual RMS", residual, cell.calibration.max_rms_mm, "mm"))
    r.results |= {
        "group": group.name,
        "measurements": seen,
        "rejected": taken.rejected,
        "rms_mm": residual,
        **_change(m, x_new, x_before),
    }
    _write_plan(ctx, views, q, ok)
    r.files.append(PLAN_FILE)
    if ctx.truth is not None:
        r.results["true_rmse_mm"] = ctx.truth.true_rmse_mm(model, x_new, ctx.sensor_model())
    return r


def group_document(
    model: Any,
    data: Measurements,
    result: IdentificationResult,
    report: GateReport | None,
    before: Path,
) -> dict[str, Any]:
    """The parameters document of a group identified on `data` with the rest held at the
    version before (the file `before`): the parameters held keep their uncertainty from the
    version before, and the group's carries theirs (its estimate follows the values held:
    calib.identify.held_sensitivity), so that the per-point U95 of `app.api.Calibration`
    counts every parameter's, not the changed group's fit alone."""
    doc = to_json(model, result, report, provenance())

    def gain(held: list[str]) -> F64:
        return held_sensitivity(model, data, result.x, result.active, held)

    with_held_covariance(doc, read_json(before), before, gain)
    return doc


def std_with_units(names: Sequence[str], std: Iterable[float]) -> dict[str, float]:
    """The identified parameters' standard uncertainties, each named with its unit: lengths
    in mm ("x_FS_mm"), angles in degrees ("rx_FS_deg"; identified in rad)."""
    out = {}
    for name, v in zip(names, std, strict=True):
        unit = unit_of(name)
        if unit == "rad":
            out[f"{name}_deg"] = float(np.degrees(v))
        else:
            out[f"{name}_{unit.replace('/', '_per_')}"] = float(v)
    return out


#: where a sensor's extra views put the sphere in the field of view, from where its plan's
#: view put it [mm]: off-axis, so that the mount's tilt and shift are told apart (at one place
#: in the field of view a tilt of the sensor and a shift of it move the sphere alike)
FOV_STEPS_MM = ((9.0, 6.0, 2.0), (-9.0, -6.0, -2.0), (9.0, -6.0, -2.0), (-9.0, 6.0, 2.0))


def _with_fov_views(
    ctx: Context,
    chosen: list[tuple[str, F64]],
    views: Views,
    index: list[int],
    rigid: Any,
    xr: F64,
) -> list[tuple[str, F64]]:
    """The sensor's views with `[commission] maintenance_fov_views` more, dealt to them in
    turn, each right after its view and a short motion away from it, seeing the same sphere
    elsewhere in the field of view (`FOV_STEPS_MM` in turn; `calib.candidates.
    neighbour_configurations`, the sensor turned 3-10 deg): a few seconds of robot time each,
    where another plan view costs a crossing of the workspace."""
    n = ctx.cell().commission.maintenance_fov_views
    rng = np.random.default_rng([ctx.cell().commission.seed, 53])
    spheres = ctx.spheres_part_mm()
    extra: list[list[tuple[str, F64]]] = [[] for _ in chosen]
    for i in range(n if chosen else 0):
        j = i % len(chosen)
        target, q = chosen[j]
        step = FOV_STEPS_MM[(i // len(chosen) + j) % len(FOV_STEPS_MM)]
        c = views.c_mm[index[j]] + np.asarray(step)
        near = candidates.neighbour_configurations(
            rigid, xr, spheres[target], q, c, 1, rng, tilt_deg=(3.0, 10.0)
        )
        extra[j] += [(target, qn) for qn in near.q_deg]
    return [v for j, view in enumerate(chosen) for v in (view, *extra[j])]


def _subset(
    views: Views,
    n: int,
    model: Any,
    x: F64,
    params: tuple[str, ...],
    *,
    seen: Sequence[int] = (),
    among: Sequence[int] | None = None,
) -> list[int]:
    """n views to measure, chosen greedily for the changed group (each adds the most
    log-determinant to the group's information, with the views `seen` already counted:
    DETMAX's D criterion on the plan's views), from `among` (default all). The plan keeps all
    of them, re-aimed."""
    if not params:
        params = BASE_NAMES  # nothing to identify: the part frame's information, a spread
    J = model.point_jacobian(x, views.q_deg, views.c_mm, params)  # (K, 3, k)
    info = np.eye(J.shape[2]) * 1e-9 + sum((J[i].T @ J[i] for i in seen), np.zeros((1, 1)))
    pool = [i for i in (range(len(views.targets)) if among is None else among) if i not in seen]
    chosen: list[int] = []
    for _ in range(min(n, len(pool))):
        gains = [float(np.linalg.slogdet(info + J[i].T @ J[i])[1]) for i in pool]
        best = pool.pop(int(np.argmax(gains)))
        chosen.append(best)
        info = info + J[best].T @ J[best]
    return sorted(chosen)


def _extend(taken: Taken, more: Taken) -> None:
    """The measurements of `more` added to `taken` (each view's once: its last)."""
    for f in dataclasses.fields(Taken):
        getattr(taken, f.name).extend(getattr(more, f.name))


def _group(m: MaintenanceContext, model: Any) -> StepGroup:
    """The group an event changes (module docstring)."""
    if m.event == "sensor":
        return StepGroup("sensor", "sensor mount", SENSOR_NAMES)
    if m.event == "fixture":
        return StepGroup("fixture", "part frame", BASE_NAMES)
    assert m.axis is not None
    if m.axis == 1:
        return StepGroup("J1", "J1 zero (the part frame's turn about the base)", BASE_NAMES)
    if m.axis == 6:
        return StepGroup("J6", "J6 zero (the sensor's turn about the flange)", SENSOR_NAMES)
    names = ("dtheta2", "dtheta3") if m.axis == 2 else (f"dtheta{m.axis}",)
    active = set(model.default_active())
    return StepGroup(f"J{m.axis}", f"J{m.axis} zero", tuple(n for n in names if n in active))


def _fixture_moved(model: Any, x: F64, data: Any, cell: Any) -> StepGroup:
    """The part frame's group when the measurements at the spheres' new places show it moved
    (BIC, calib.attribution), else nothing (the spheres moved alone: the kinematics hold)."""
    sigma = float(cell.service.seq_measurement_std_mm)
    groups = (StepGroup(NONE, "nothing", ()), StepGroup("fixture", "part frame", BASE_NAMES))
    a = attribute(model, x, data, sigma_mm=sigma, groups=groups)
    return groups[1] if a.choice == "fixture" else groups[0]


def _change(m: MaintenanceContext, x: F64, x_before: F64) -> dict[str, float]:
    """What the procedure changed, in its own terms."""
    if m.event == "axis" and m.axis is not None:
        return {"zero_change_deg": zero_of(x, x_before, m.axis)}
    names = SENSOR_NAMES if m.event == "sensor" else BASE_NAMES
    from calib.model import INDEX

    d = np.array([x[INDEX[n]] - x_before[INDEX[n]] for n in names])
    return {
        "translation_mm": float(np.linalg.norm(d[:3])),
        "rotation_deg": float(np.degrees(np.linalg.norm(d[3:]))),
    }


def _write_plan(ctx: Context, views: Views, q: F64, ok: np.ndarray) -> None:
    """The plan with its views re-aimed (a view that could not be kept its old one) and the
    spheres' places now."""
    doc = read_json(ctx.path(PLAN_FILE))
    positions = ctx.spheres_part_mm()
    k = 0
    for sphere in doc["spheres"]:
        sphere["position_part_mm"] = [float(v) for v in positions[sphere["name"]]]
        for conf in sphere["configurations"]:
            if ok[k]:
                conf["q_deg"] = [float(v) for v in q[k]]
            k += 1
    doc["maintenance"] = {"re_aimed": int(ok.sum()), "views": len(ok)}
    write_json(ctx.path(PLAN_FILE), doc)
