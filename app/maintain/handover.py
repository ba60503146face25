"""The hand-over of a maintenance procedure to `rvis run` (app/maintain/__init__.py)."""

from __future__ import annotations

from app.commission.checks import StepResult, holds
from app.commission.context import Context
from app.commission.files import PARAMS_FILE, PLAN_FILE, SENSOR_FILE, WORKSPACE_ERRORS_FILE
from app.commission.workspace import workspace_evidence_mm
from app.config.write import dumps_cell
from app.formats.files import read_json, write_bytes, write_text
from app.line.params_store import MAINTENANCE_SOURCE, ParamsStore, hand_over
from app.line.states import AlarmCode
from app.line.store import Store
from app.maintain.context import MaintenanceContext
from app.maintain.workspace import rms_mm


def handover(ctx: Context) -> StepResult:
    """The procedure's parameters as the next version (source maintenance, with its workspace
    validation), the re-aimed plan, the sensor calibration and the spheres' places into the
    state directory; the service's maintenance alarm cleared, its open suspect intervals
    closed at the hand-over, the maintenance record completed. Run again after a kill, it finds
    its own version in force and completes the rest."""
    m, state, r = MaintenanceContext.of(ctx), ctx.state, StepResult()
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
        after = {"validation_rmse_mm": rms_mm(errors), "version": version}
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
