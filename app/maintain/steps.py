"""The maintenance procedures' own steps (app/maintain/__init__.py): what the state directory
holds now, the axis's zero found, the plan's views re-aimed and the changed group identified
on the spheres, and the hand-over to `rvis run`. The steps they share with the commissioning
(the devices' answers, the sensor calibration, the tracker's spheres, the acceptance, the
workspace validation) are the commissioning's, run in the procedure's folder on the files
`prepare` puts there (the same names: app/commission/files.py)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.checks import Check, StepResult, at_least, at_most, count_at_least, holds
from app.commission.context import Context
from app.commission.files import (
    MAINTENANCE_MEASUREMENTS_FILE,
    PARAMS_BEFORE_FILE,
    PARAMS_FILE,
    PLAN_FILE,
    SENSOR_FILE,
    TARGETS_BEFORE_FILE,
    TARGETS_FILE,
    WORKSPACE_ERRORS_FILE,
)
from app.commission.measuring import Taken, measure_views
from app.commission.steps import device_checks
from app.commission.workspace import workspace_evidence_mm
from app.config.write import dumps_cell
from app.formats.files import (
    read_json,
    read_targets,
    write_bytes,
    write_json,
    write_targets,
    write_text,
)
from app.formats.params import from_json, to_json, with_held_covariance
from app.line.measure import Rejected
from app.line.params_store import MAINTENANCE_SOURCE, ParamsStore, hand_over
from app.line.states import AlarmCode
from app.line.store import Store
from app.maintain.aim import reaim, zero_moved, zero_of
from app.meta import provenance
from app.motion import shortest_route
from app.planning import read_plan
from calib import candidates
from calib.attribution import NONE, StepGroup, attribute
from calib.errors import InsufficientData, NotIdentifiable
from calib.gates import GateReport, check_identification
from calib.identify import IdentificationResult, Measurements, held_sensitivity, identify
from calib.model import BASE_NAMES, SENSOR_NAMES, unit_of
from calib.uncertainty import larger_rms_bound, shown_larger_than
from calib.validation import rmse

F64 = NDArray[np.float64]

#: the search for an axis's zero where no sphere is seen: steps [deg] up to the limit
ZERO_STEP_DEG = 0.2
ZERO_LIMIT_DEG = 1.4


@dataclass
class MaintenanceContext(Context):
    """The commissioning's Context with what the procedure is for: the event ("sensor",
    "axis", "fixture"), the axis (1..6 for "axis") and the database's maintenance record."""

    event: str = ""
    axis: int | None = None
    record_id: int | None = None


def _m(ctx: Context) -> MaintenanceContext:
    assert isinstance(ctx, MaintenanceContext)
    return ctx


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


# -- the views, re-aimed ------------------------------------------------------------------------
@dataclass(frozen=True)
class Views:
    """The plan's views: sphere of each, planned configuration (K, 6), planned centre (K, 3)."""

    targets: tuple[str, ...]
    q_deg: F64
    c_mm: F64

    @staticmethod
    def of_plan(ctx: Context) -> Views:
        _, qs, cs = read_plan(ctx.path(PLAN_FILE))
        targets = tuple(t for t, q in qs.items() for _ in range(len(q)))
        return Views(targets, np.vstack(list(qs.values())), np.vstack(list(cs.values())))


def _rigid(ctx: Context, x: F64) -> tuple[Any, F64]:
    """The rigid chain the plan was made on, and x's share of it."""
    model = ctx.cell().model()
    return model, np.asarray(x, dtype=float)[: len(model.nominal_x())]


def _aimed(ctx: Context, views: Views, x_now: F64) -> tuple[F64, np.ndarray]:
    """The views re-aimed on x_now at the spheres' places now (TARGETS_FILE)."""
    _, x_plan = from_json(ctx.path(PARAMS_BEFORE_FILE))
    model, xp = _rigid(ctx, x_plan)
    _, xn = _rigid(ctx, x_now)
    p_now = ctx.spheres_part_mm()
    p = np.array([p_now[t] for t in views.targets])
    return reaim(model, xp, xn, views.q_deg, views.c_mm, p)


# -- axis N: the zero -----------------------------------------------------------------------------
def zero(ctx: Context) -> StepResult:
    """The axis's zero, found from one view of the plan: measured as it is; where its sphere is
    not seen, the view re-aimed on the zero moved by +-0.2, +-0.4, ... deg until it is; the
    zero then solved from that measurement (the rest held). Writes the parameters with it."""
    m = _m(ctx)
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
        q, ok = _aimed(ctx, Views(*_pick(views, [first])), x_try)
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
    axis = _m(ctx).axis
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


# -- the changed group, identified ---------------------------------------------------------
def reidentify(ctx: Context) -> StepResult:
    """The plan's views re-aimed on the parameters so far at the spheres' places now, measured
    from home and back, and the changed group identified with the rest held at the version in
    force: the sensor's 6 (sensor), the axis's zero (axis; J2's moves theta3 with it; J1's and
    J6's are the part frame's and the sensor's), the part frame (fixture) only if the
    measurements show it moved (BIC against nothing moved). Checked: views seen, residual RMS,
    condition, the change against the offline gates. Writes the parameters and the plan."""
    m = _m(ctx)
    cell = ctx.cell()
    model, x_start = from_json(ctx.path(PARAMS_FILE))
    _, x_before = from_json(ctx.path(PARAMS_BEFORE_FILE))
    views = Views.of_plan(ctx)
    q, ok = _aimed(ctx, views, x_start)
    r = StepResult()
    limit = cell.commission.max_rejected_fraction
    n_all = len(ok)
    r.checks.append(count_at_least("views re-aimed", int(ok.sum()), n_all, n_all * (1 - limit)))
    sensor = ctx.sphere_sensor(ctx.sensor_model())
    rigid, xr = _rigid(ctx, x_start)
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
        q, ok = _aimed(ctx, views, x_new)
        _, xr = _rigid(ctx, x_new)
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


def workspace(ctx: Context) -> StepResult:
    """The paper's workspace validation (the commissioning's step) at `[commission]
    maintenance_positions` positions, `maintenance_workspace_views` views each, stated against
    the limit in force (the hand-over keeps the state directory's), and compared with the
    version in force before (`compare_workspace`: said in words, a warning when shown worse)."""
    from app.commission.workspace import workspace_validation

    if ctx.station.tracker is None:
        return StepResult(not_run=NO_TRACKER)
    cell = ctx.cell()
    c = cell.commission
    in_force = float(cell.service.accuracy_limit_mm)
    limit = (in_force, LIMIT_KEPT) if in_force > 0 else None
    r = workspace_validation(ctx, c.maintenance_positions, c.maintenance_workspace_views, limit)
    before_file = ctx.path(PARAMS_BEFORE_FILE)
    doc = read_json(before_file) if before_file.is_file() else {}
    before = [float(e) for e in (doc.get("validation") or {}).get("errors_mm") or []]
    after = workspace_evidence_mm(ctx.path(WORKSPACE_ERRORS_FILE))
    if before and after:
        text, check, worse = compare_workspace(after, before)
        r.results |= {"workspace_rmse_before_mm": _rms(before), "workspace_change": text}
        r.results["workspace_shown_worse"] = worse
        r.checks.append(check)
    return r


#: the basis of the limit a maintenance states its U95 against
LIMIT_KEPT = (
    "the state directory's (cell.toml, written by the commissioning); the hand-over keeps it"
)


def compare_workspace(
    after_mm: Sequence[float], before_mm: Sequence[float]
) -> tuple[str, Check, bool]:
    """The workspace validation after a maintenance against the version's before it (one error
    norm per position each): the change in words ("workspace RMS 0.0570 -> 0.0700 mm: worse by
    0.0130 mm (+23 %), not shown worse at 95 % ..."), the ratio as a figure of the checks table,
    and whether the after is shown worse at 95 % (a one-sided F test of the two sets' mean
    squares, calib.uncertainty.shown_larger_than; the report then warns).

    The rule: stated, never failed. The figure before is the version in force's own
    validation, taken at its time and temperature (a commissioning's: 20 positions from one
    view each, a cold cell), so the difference holds the cell's drift since as well as what the
    procedure did. What decides whether the cell may measure is the plant's: the absolute
    `[commission] max_workspace_rmse_mm` of this step, and the U95 from these errors against
    the limit in force, which the report states beside it (a warning when above: the
    service's windows are suspect until its own measurements bring U95 under the limit). On
    the simulated line's axis 3 procedure on seed 17 it warned where the truth agrees: 0.061
    -> 0.083 mm, shown worse, the truth 0.082 mm where the cell without the event is at 0.060.
    """
    a, b = _rms(list(after_mm)), _rms(list(before_mm))
    assert a is not None and b is not None
    bound = larger_rms_bound(len(after_mm), len(before_mm))
    worse = shown_larger_than(after_mm, before_mm)
    delta = a - b
    way = "worse" if delta > 0 else "better"
    change = f"{way} by {abs(delta):.4f} mm ({100 * delta / b:+.0f} %)" if b else way
    if abs(delta) < 0.00005:
        change = "unchanged"
    if delta <= 0:
        verdict = ""
    elif worse:
        verdict = f", shown worse at 95 % (beyond {bound:.2f}x)"
    else:
        verdict = f", not shown worse at 95 % (that needs more than {bound:.2f}x)"
    counts = f" from {len(after_mm)} positions after and {len(before_mm)} before"
    text = f"workspace RMS {b:.4f} -> {a:.4f} mm: {change}{verdict}{counts}"
    ratio = a / b if b else float("inf")
    check = Check(
        f"workspace RMS, after / before ({a:.4f} mm / {b:.4f} mm)", ratio, "", True, "", ".4f"
    )
    return text, check, worse


def _pick(views: Views, ks: list[int]) -> tuple[tuple[str, ...], F64, F64]:
    return tuple(views.targets[k] for k in ks), views.q_deg[ks], views.c_mm[ks]


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


def spheres_located(ctx: Context) -> StepResult:
    """A fixture renewed with no tracker at hand: each sphere located by the robot with the
    version in force, from every view the plan has of it (aimed where the cell file had it:
    a renewal moves a sphere by millimetres, within the measuring volume), its place the mean
    of the views' centres in the part frame. The places carry the version in force's error at
    those views and nothing independent checks them: the robot and the sensor did not change,
    so the cell keeps the accuracy it had, and the workspace validation does not run
    (NO_TRACKER). Checked: every sphere seen from two views or more, its views agreeing within
    `[commission] max_target_rms_mm` (RMS about their mean), near the cell file's place."""
    c = ctx.cfg.commission
    model, x = from_json(ctx.path(PARAMS_BEFORE_FILE))
    views = Views.of_plan(ctx)
    taken = measure_views(
        ctx,
        list(zip(views.targets, views.q_deg, strict=True)),
        ctx.sphere_sensor(ctx.sensor_model()),
        "locate the spheres:",
    )
    temps = None if any(t is None for t in taken.temp_c) else np.array(taken.temp_c, float)
    points = model.points_part(
        x, np.array(taken.q_deg).reshape(-1, 6), np.array(taken.c_sensor_mm).reshape(-1, 3),
        temp_c=temps,
    )  # fmt: skip
    before = read_targets(ctx.path(TARGETS_BEFORE_FILE))
    r = StepResult()
    r.results["source"] = "located by the robot with the version in force (no tracker)"
    r.results["spheres"], positions, moved = {}, {}, {}
    for t in before:
        mine = points[[k for k, s in enumerate(taken.targets) if s == t]]
        r.checks.append(at_least(f"{t} seen from", len(mine), 2, "views"))
        if len(mine) < 2:
            continue
        p = mine.mean(axis=0)
        spread = float(np.sqrt(np.mean(np.sum((mine - p) ** 2, axis=1))))
        positions[t], moved[t] = p, float(np.linalg.norm(p - before[t]))
        x_mm, y_mm, z_mm = map(float, p)
        r.results["spheres"][t] = {
            "x_mm": x_mm, "y_mm": y_mm, "z_mm": z_mm, "views": len(mine), "rms_mm": spread,
            "offset_mm": moved[t],
        }  # fmt: skip
        r.checks.append(
            at_most(f"{t} views' RMS about their mean", spread, c.max_target_rms_mm, "mm")
        )
        r.checks.append(at_most(f"{t} from the cell file", moved[t], c.max_sphere_offset_mm, "mm"))
    r.results["moved_mm"] = moved
    r.results["rejected"] = taken.rejected
    if len(positions) == len(before):
        write_targets(ctx.path(TARGETS_FILE), positions)
        r.files.append(TARGETS_FILE)
    return r


# -- the hand-over --------------------------------------------------------------------------
def handover(ctx: Context) -> StepResult:
    """The procedure's parameters as the next version (source maintenance, with its workspace
    validation), the re-aimed plan, the sensor calibration and the spheres' places into the
    state directory; the service's maintenance alarm cleared, its open suspect intervals
    closed at the hand-over, the maintenance record completed. Run again after a kill, it finds
    its own version in force and completes the rest."""
    m, state, r = _m(ctx), ctx.state, StepResult()
    doc = read_json(ctx.path(PARAMS_FILE))
    errors = workspace_evidence_mm(ctx.path(WORKSPACE_ERRORS_FILE))
    folder = str(ctx.folder.relative_to(state.root))
    doc = {
        **doc,
        "source": MAINTENANCE_SOURCE,
        "reason": _reason(m),
        "maintenance": {"event": m.event, "axis": m.axis, "folder": folder},
    }
    if errors:
        doc["validation"] = {"errors_mm": errors, "what": "maintenance workspace step"}
    write_bytes(state.plan, ctx.path(PLAN_FILE).read_bytes())
    write_bytes(state.sensor, ctx.path(SENSOR_FILE).read_bytes())
    cell = ctx.cell()
    write_text(state.cell, dumps_cell(cell, f"written by rvis maintain {_reason(m)}"))
    params = ParamsStore(state.root)
    store = Store(state.db)
    try:
        t = ctx.clock.time()
        current = params.current_document() or {}
        ours = (current.get("maintenance") or {}).get("folder") == folder
        version = params.current_version() if ours else None
        if version is None or not any(a["version"] == version for a in store.applied()):
            version = hand_over(params, store, doc, t) if not ours else version
            if ours and version is not None:
                store.add_applied(t, version, None, MAINTENANCE_SOURCE, None)
        assert version is not None
        after = {"validation_rmse_mm": _rms(errors), "version": version}
        with store.batch():  # the rest of the hand-over: all or nothing
            closed = _close_suspects(store, t, version)
            # the service's alarms cleared by the one writer of alarm state, each with its
            # `alarm_cleared` event (a consumer following the events learns it, as when the
            # service clears one)
            store.clear_alarms(t, AlarmCode.MAINTENANCE)
            store.clear_alarms(t, AlarmCode.DRIFT_STEP)
            store.clear_alarms(t, AlarmCode.VIEW_LOST)
            if m.record_id is not None:
                store.finish_maintenance(m.record_id, t, version, after)
            what = {"event": m.event, "axis": m.axis, "version": version, "folder": folder}
            store.add_event(t, "maintenance", what)
        applied = [a["version"] for a in store.applied()]
    finally:
        store.close()
    r.results = {"version": version, "suspect_intervals_closed": closed, **after}
    r.results["run"] = "rvis run" if ctx.truth is None else _sim_run(ctx)
    r.checks += [
        holds(
            "params/current.json is the procedure's version", params.current_version() == version
        ),
        holds("rvis.db records it applied", applied[-1] == version, f"versions {applied}"),
        holds(
            "cell.toml, plan.json, sensor.toml written",
            all(p.is_file() for p in (state.cell, state.plan, state.sensor)),
        ),
    ]
    return r


def _reason(m: MaintenanceContext) -> str:
    what = {"sensor": "sensor replaced", "fixture": "sphere fixture renewed"}
    return f"maintenance: {what.get(m.event, f'axis {m.axis} motor or encoder replaced')}"


def _sim_run(ctx: Context) -> str:
    truth = ctx.truth
    geometric = " --geometric" if truth.geometric else ""
    return f"rvis run --sim{geometric} --seed {truth.seed} --state-dir {ctx.state.root}"


def _close_suspects(store: Store, t: float, version: int) -> int:
    """Close every open suspect interval at the hand-over: the bodies measured in it were
    measured with the parameters of before the change."""
    n = 0
    for row in store.suspects():
        if row["t_end"] is None:
            store.update_suspect(
                int(row["id"]), t_end=t, end_reason="maintenance", end_version=version
            )
            n += 1
    return n


def _rms(errors: list[float]) -> float | None:
    return float(np.sqrt(np.mean(np.square(errors)))) if errors else None


# -- the fixture's spheres --------------------------------------------------------------------
#: why the workspace validation does not run without a tracker
NO_TRACKER = (
    "no tracker at hand: the cell's accuracy after the procedure is not validated against an"
    " independent reference (the accuracy statement's floor stays the commissioning's workspace"
    " validation); measure the spheres with a tracker when one is at hand (`rvis maintain"
    " fixture --targets FILE`)"
)


def without_tracker(fields: dict[str, Any]) -> dict[str, Any]:
    """A procedure's context fields with the cell's tracker left out (`--no-tracker`: none at
    hand today; the fixture's spheres are then located by the robot)."""
    return fields | {"station": dataclasses.replace(fields["station"], tracker=None)}


def spheres_moved(ctx: Context) -> StepResult:
    """The commissioning's spheres step (the tracker measures them again, TARGETS_FILE), and
    how far each moved from where the cell file had it; with no tracker at hand (none in the
    station and no export), the spheres located by the robot (`spheres_located`)."""
    from app.commission.steps import spheres

    if ctx.targets_file is None and ctx.station.tracker is None:
        return spheres_located(ctx)
    r = spheres(ctx)
    if not ctx.path(TARGETS_FILE).is_file():
        return r
    before = read_targets(ctx.path(TARGETS_BEFORE_FILE))
    now = read_targets(ctx.path(TARGETS_FILE))
    moved = {t: float(np.linalg.norm(now[t] - before[t])) for t in now if t in before}
    r.results["moved_mm"] = moved
    r.checks.append(at_least("spheres measured again", len(moved), len(before)))
    return r
