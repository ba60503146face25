"""The commissioning steps that need no motion: the devices, the sensor calibration, the sphere
positions and the plan. Each takes the Context and returns a StepResult whose checks decide
whether the next step may start (the limits are `[commission]`, `[calibration]` and
`[planning]` of the cell file)."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import numpy as np

from app.commission.checks import Check, StepResult, at_least, at_most, holds, ratio_at_least
from app.commission.context import Context
from app.commission.files import (
    PLAN_FILE,
    PRECALIBRATION_PARAMS_FILE,
    SENSOR_DATA_DIR,
    SENSOR_FILE,
    TARGETS_FILE,
    TRACKER_EXPORT_FILE,
)
from app.commission.measuring import precalibrated_x
from app.devicecheck import describe_and_probe
from app.errors import InputError
from app.formats.files import write_csv, write_json, write_targets, write_text
from app.formats.sweeps import calibrate_dir
from app.meta import provenance
from app.planning import plan_to_json, run_plan
from drivers import open_tracker
from drivers.errors import DeviceError
from drivers.tracker_file import OPTIONAL_NUMBERS, REQUIRED, ExportError, read_targets_csv
from vision.errors import SensorFileError
from vision.sensor_model import dumps_sensor_model, load_sensor_model

NEEDED = ("robot", "plc", "camera", "galvo")


def devices(ctx: Context) -> StepResult:
    """Every device answers; the robot stands at home without an alarm; the PLC is alive;
    the state directory holds no calibration yet."""
    r = device_checks(ctx)
    fresh = not ctx.state.current.exists() and not ctx.state.db.exists()
    r.checks.append(holds("state directory without a calibration", fresh, str(ctx.state.root)))
    return r


def device_checks(ctx: Context) -> StepResult:
    """Every device answers; the robot stands at home without an alarm; the PLC is alive."""
    r = StepResult()
    opened = ctx.station.devices()
    for family in NEEDED:
        if family not in opened:
            r.checks.append(holds(f"{family} configured", False, "no URL in [devices]"))
    for family, device in opened.items():
        try:
            detail, ok = describe_and_probe(device), True
        except DeviceError as exc:
            detail, ok = f"{type(exc).__name__}: {exc}", False
        r.checks.append(holds(f"{family} answers", ok, "yes" if ok else detail))
        r.results[family] = {"url": ctx.station.urls.get(family, ""), "answer": detail}
    q = ctx.station.robot.joints_deg()
    r.checks.append(holds("robot at home", ctx.at_home(), ", ".join(f"{v:.2f}" for v in q)))
    status = ctx.station.robot.status()
    r.checks.append(holds("robot without alarm", not status.fault, status.detail or "none"))
    r.checks.append(holds("PLC heartbeat alive", _plc_alive(ctx)))
    return r


def _plc_alive(ctx: Context) -> bool:
    """The PLC's heartbeat changes within its timeout (the PLC is opened read-only)."""
    plc, clock = ctx.station.plc, ctx.clock
    first = plc.poll().heartbeat
    deadline = clock.monotonic() + plc.heartbeat_timeout_s
    while plc.poll().heartbeat == first:
        if clock.monotonic() > deadline:
            return False
        clock.sleep(plc.poll_s)
    return True


def sensor(ctx: Context) -> StepResult:
    """The sensor calibration: from a file made elsewhere (--sensor), from targets recorded
    earlier (--sensor-data), or from targets captured now; its reprojection and laser-plane
    residuals within limits."""
    c = ctx.cfg.commission
    r = StepResult()
    if ctx.sensor_file is not None:
        try:
            model = load_sensor_model(ctx.sensor_file)
        except SensorFileError as exc:
            raise InputError(exc.reason, file=ctx.sensor_file, field=exc.field) from exc
        r.results["source"] = f"file {ctx.sensor_file}"
    else:
        data = ctx.sensor_data
        if data is None:
            data = ctx.path(SENSOR_DATA_DIR)
            shutil.rmtree(data, ignore_errors=True)
            ctx.capture.capture(data, ctx)
            r.files.append(f"{SENSOR_DATA_DIR}/")
        r.results["source"] = f"targets in {data}"
        model = calibrate_dir(data)
    write_text(ctx.path(SENSOR_FILE), dumps_sensor_model(model))
    r.files.append(SENSOR_FILE)
    reproj, plane = model.camera.rms_reprojection_px, model.laser.rms_plane_mm
    K = model.camera.K
    r.results |= {"fx_px": K[0, 0], "fy_px": K[1, 1], "cx_px": K[0, 2], "cy_px": K[1, 2]}
    if ctx.truth is not None:  # the simulated line: against its true sensor, never checked
        r.results["truth"] = ctx.truth.sensor_errors(model)
    r.checks.append(_recorded_at_most("reprojection RMS", reproj, c.max_reprojection_px, "px"))
    r.checks.append(_recorded_at_most("laser plane RMS", plane, c.max_plane_rms_mm, "mm"))
    return r


def _recorded_at_most(name: str, value: float | None, limit: float, unit: str) -> Check:
    if value is None:
        return holds(f"{name} recorded in the file", False, "missing")
    return at_most(name, value, limit, unit)


def spheres(ctx: Context) -> StepResult:
    """Sphere positions (part frame) from the tracker's export (--targets), or measured by the
    cell's tracker into one, imported through tracker+file://: every sphere of the cell file
    present, within its RMS limit, near the cell file's position, and far enough apart."""
    c = ctx.cfg.commission
    r = StepResult()
    ids = list(ctx.cfg.spheres_part_mm)
    export = ctx.path(TRACKER_EXPORT_FILE)
    if ctx.targets_file is not None:
        _read_export(ctx.targets_file)  # a bad file named as the user gave it, not our copy
        export.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ctx.targets_file, export)
        r.results["source"] = f"tracker export {ctx.targets_file}"
    elif ctx.station.tracker is not None:
        _measure_export(ctx, ids, export)
        r.results["source"] = f"measured by {ctx.station.tracker.describe()}"
    else:
        r.checks.append(holds("a tracker export (--targets) or a tracker", False))
        return r
    r.files.append(export.name)
    try:
        tracker = open_tracker(f"tracker+file://{export}", max_rms_mm=1e6)
    except ExportError as exc:
        raise InputError(exc.reason, file=exc.path, line=exc.line, field=exc.field) from exc
    except DeviceError as exc:
        raise InputError(str(exc), file=export) from exc
    with tracker:
        known = set(tracker.targets())
        missing = [t for t in ids if t not in known]
        r.checks.append(export_check(ids, missing))
        found = {t: tracker.measure(t) for t in ids if t in known}
    positions = {t: m.point_mm for t, m in found.items()}
    r.results["spheres"] = {}
    for t, m in found.items():
        offset = float(np.linalg.norm(m.point_mm - ctx.cfg.spheres_part_mm[t]))
        x_mm, y_mm, z_mm = map(float, m.point_mm)
        r.results["spheres"][t] = {
            "x_mm": x_mm,
            "y_mm": y_mm,
            "z_mm": z_mm,
            "rms_mm": m.rms_mm,
            "offset_mm": offset,
        }
        r.checks.append(at_most(f"{t} tracker RMS", m.rms_mm, c.max_target_rms_mm, "mm"))
        r.checks.append(at_most(f"{t} from the cell file", offset, c.max_sphere_offset_mm, "mm"))
    pairs = list(itertools.combinations(positions.values(), 2))
    if pairs:
        gap = min(float(np.linalg.norm(a - b)) for a, b in pairs)
        limit = float(ctx.cfg.planning.min_separation_mm)
        r.checks.append(at_least("closest two spheres", gap, limit, "mm"))
    if not missing:
        write_targets(ctx.path(TARGETS_FILE), positions)
        r.files.append(TARGETS_FILE)
    return r


def _read_export(path: Path) -> None:
    """A tracker export read as the tracker+file:// driver reads it; InputError naming the
    file once, with its line and field."""
    try:
        read_targets_csv(path)
    except ExportError as exc:
        raise InputError(exc.reason, file=path, line=exc.line, field=exc.field) from exc


def export_check(ids: list[str], missing: list[str]) -> Check:
    """Every sphere of the cell file in the tracker's export: "missing P3, P4" (of "all of P1,
    P2, P3, P4") or "all 4"."""
    value = f"missing {', '.join(missing)}" if missing else f"all {len(ids)}"
    return Check("every sphere in the export", value, f"all of {', '.join(ids)}", not missing)


def _measure_export(ctx: Context, ids: list[str], export: Path) -> None:
    """Measure every sphere with the cell's tracker and write the export (tracker+file)."""
    tracker = ctx.station.tracker
    assert tracker is not None
    rows = []
    for t in ids:
        ctx.ask(f"tracker: measure sphere {t} (its nest ready)?")
        m = tracker.measure(t)
        rows.append(
            [t, *map(float, m.point_mm), m.rms_mm, m.time_utc, m.temperature_c, m.pressure_hpa]
        )
    columns = (*REQUIRED, OPTIONAL_NUMBERS[0], "time_utc", *OPTIONAL_NUMBERS[1:])
    write_csv(export, columns, rows)


def plan(ctx: Context) -> StepResult:
    """The measurement configurations at the measured sphere positions (placement fixed: the
    spheres stand where they are), planned on the pre-calibration's parameters (the paper's
    order: its hand-eye and base put each planned view's sphere where the plan aims in the
    cell as built): full rank, condition within [calibration] max_condition, better than
    random views at the same positions, every sphere its configurations."""
    cell = ctx.cell()
    model = cell.model()
    x = precalibrated_x(ctx)
    result = run_plan(cell, model, x, placement="fixed")
    doc = {
        **plan_to_json(cell, model, x, result),
        "planned_on": PRECALIBRATION_PARAMS_FILE,  # the parameters its IK used
        "provenance": provenance(result.settings.seed),
    }
    write_json(ctx.path(PLAN_FILE), doc)
    obs, rnd = result.observability, result.random_observability
    n = cell.calibration.configs_per_sphere
    r = StepResult(files=[PLAN_FILE])
    r.results = {
        "planned": {"O1": obs.indices["O1"], "condition": obs.condition, "rank": obs.rank},
        "random": {"O1": rnd.indices["O1"], "condition": rnd.condition, "rank": rnd.rank},
        "planned_on": "the pre-calibration's parameters",
        "seconds": result.seconds,
    }
    r.checks.append(at_least("rank", obs.rank, len(result.settings.active)))
    r.checks.append(at_most("condition", obs.condition, cell.calibration.max_condition))
    o1 = obs.indices["O1"], rnd.indices["O1"]
    r.checks.append(ratio_at_least("O1, planned / random", *o1))
    counts = {sp.name: len(sp.q_deg) for sp in result.spheres}
    short = [k for k, v in counts.items() if v < n]
    r.checks.append(holds(f"{n} configurations per sphere", not short, ", ".join(short)))
    return r
