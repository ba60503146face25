"""The paper's validation (Yu, Chen & Xi 2018, section 4, eq. 19), the protocol a plant audits:
a sphere on a tracker nest placed at N positions spread over the workspace (`[commission]
workspace_positions`, default 20; the paper used 100), each measured by the laser tracker
(`[commission] validation_target`, the nest's reflector) and by rvis from a configuration it
chooses on the calibrated model (a random reachable view: none the calibration used). The error
of each position is the distance between the point rvis computes in the part frame and the
tracker's; the step reports RMS, mean, max, the 95th percentile and a 95 % bootstrap interval
of the RMS (the mean, largest and 95th percentile stated with the checks, only the RMS held to
a limit), and writes every position's error (`workspace_errors.csv`). This is the end-to-end
error the inspection software sees; the quick check (the `validation` step) measures only the
calibration's own spheres again and is labelled as such.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.checks import (
    MM,
    StepResult,
    at_most,
    count_at_least,
    holds,
    ratio_at_most,
    stated,
)
from app.commission.context import Context
from app.commission.files import PARAMS_FILE, WORKSPACE_ERRORS_FILE
from app.commission.measuring import measure_views
from app.formats.files import ERROR_COLUMNS, csv_rows, write_csv
from app.formats.params import from_json
from app.workspace import workspace_points
from calib import candidates
from calib.identify import Measurements
from calib.uncertainty import DEFAULT_TOLERANCE_MM, VDA5_MAX_RATIO, accuracy_limit_mm, u95_mm
from calib.validation import rmse

F64 = NDArray[np.float64]

#: what the workspace step's `u95_mm` is (the report's headline says it with the figure)
U95_WHAT = (
    "the expanded uncertainty (95 %) of a point measured now, 3-D: the distance from a"
    " point the cell measures to its true place is within it for 95 % of points; the upper"
    " 95 % bound from the workspace positions' end-to-end errors (tracker against rvis, one"
    " error per position): the accuracy statement the in-line service starts from"
)


def tolerance_note(tolerance_mm: float) -> str:
    """What `[commission] tolerance_mm` is taken to be: the full range T of the features'
    tolerance (+-0.5 mm is 1.0), or (0) not given."""
    if tolerance_mm <= 0:
        return (
            "not given ([commission] tolerance_mm 0); the limit assumes"
            f" T = {DEFAULT_TOLERANCE_MM:g} mm (+-{DEFAULT_TOLERANCE_MM / 2:g} mm)"
        )
    return (
        f"T = {tolerance_mm:g} mm, the full range of the features' tolerance"
        f" (+-{tolerance_mm / 2:g} mm; +-0.5 mm is 1.0)"
    )


def tolerance_question(tolerance_mm: float, u95: float) -> str:
    """A tolerance_mm that may be a half-range, questioned ("" when it is not): whenever the
    cell's U95 fails VDA 5 against it (2 U95 / T above 30 %), the reading of T decides the
    verdict, and a half-range entered as T (0.5 for +-0.5 mm) doubles the ratio; the text
    says what the ratio would be if T were twice the value given. A passing ratio is not
    questioned (a half-range there makes the limit stricter, not the verdict wrong), but the
    report always states T as +-T/2 (`tolerance_note`)."""
    if tolerance_mm <= 0 or not np.isfinite(u95):
        return ""
    ratio = 2.0 * u95 / tolerance_mm
    if ratio <= VDA5_MAX_RATIO:
        return ""
    doubled = ratio / 2.0
    verdict = "would pass" if doubled <= VDA5_MAX_RATIO else "would still fail"
    return (
        f"check tolerance_mm: {tolerance_mm:g} mm is read as the full range T"
        f" (+-{tolerance_mm / 2:g} mm), and the cell's U95 {u95:.4f} mm fails VDA 5 against it"
        f" (2 U95 / T = {100 * ratio:.0f} % > {100 * VDA5_MAX_RATIO:.0f} %); if the features'"
        f" tolerance is +-{tolerance_mm:g} mm, set tolerance_mm = {2 * tolerance_mm:g}"
        f" (2 U95 / T = {100 * doubled:.0f} %: {verdict})"
    )


def accuracy_results(
    u95: float, tolerance_mm: float, limit: tuple[float, str] | None = None
) -> dict[str, Any]:
    """The step's accuracy statement: the cell's U95 and what it is, the tolerance as read,
    VDA 5's ratio 2 U95 / T or why none is stated, the question of a tolerance that may be a
    half-range, and the limit the service holds U95 to with its basis (`limit`: the one in
    force, else the one the commissioning writes: calib.uncertainty.accuracy_limit_mm, as the
    ready step computes it)."""
    out: dict[str, Any] = {"u95_mm": u95, "u95_what": U95_WHAT, "tolerance_mm": tolerance_mm}
    out["tolerance"] = tolerance_note(tolerance_mm)
    if tolerance_mm > 0:
        out["vda5_ratio"] = 2.0 * u95 / tolerance_mm
        if question := tolerance_question(tolerance_mm, u95):
            out["tolerance_question"] = question
    else:
        out["vda5_ratio_not_stated"] = (
            "no tolerance given ([commission] tolerance_mm: the full range of the features'"
            " tolerance, +-0.5 mm is 1.0); the limit assumes"
            f" T = {DEFAULT_TOLERANCE_MM:g} mm (+-{DEFAULT_TOLERANCE_MM / 2:g} mm)"
        )
    value, why = limit if limit is not None else accuracy_limit_mm(tolerance_mm, u95)
    return out | {"accuracy_limit_mm": value, "accuracy_limit_basis": why}


def rms_interval(d_mm: F64, rng: np.random.Generator, n_boot: int = 2000) -> tuple[float, float]:
    """A 95 % bootstrap interval [mm] of the RMS of the distances d_mm (n,)."""
    d = np.asarray(d_mm, dtype=np.float64)
    idx = rng.integers(0, len(d), (n_boot, len(d)))
    boot = np.sqrt(np.mean(d[idx] ** 2, axis=1))
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(lo), float(hi)


def view_name(position: str, j: int) -> str:
    """The name of a position's j-th view (from 0) in `workspace_errors.csv`: V001, V001.2 .."""
    return position if j == 0 else f"{position}.{j + 1}"


def position_norms_mm(view_names: list[str], d_mm: list[float]) -> list[float]:
    """One error norm [mm] per position: the RMS of its views' norms (`view_name`), in the
    order the positions first appear."""
    by: dict[str, list[float]] = {}
    for name, e in zip(view_names, d_mm, strict=True):
        by.setdefault(name.split(".")[0], []).append(float(e) ** 2)
    return [float(np.sqrt(np.mean(v))) for v in by.values()]


def workspace_evidence_mm(path: Path) -> list[float]:
    """A workspace validation's errors as the evidence of the cell's U95 (a version's
    `validation.errors_mm`): one norm per position (`position_norms_mm`); [] without the
    file."""
    if not path.is_file():
        return []
    rows = [row for _, row in csv_rows(path, ERROR_COLUMNS)]
    return position_norms_mm([str(r["target"]) for r in rows], [float(r["e_mm"]) for r in rows])


def workspace_validation(
    ctx: Context,
    positions: int | None = None,
    views_per_position: int = 1,
    limit: tuple[float, str] | None = None,
) -> StepResult:
    """Place, track and measure the validation sphere at each workspace position (`[commission]
    workspace_positions`, or `positions`), from `views_per_position` views each: the first a
    random reachable one from home, the others near it (`candidates.neighbour_configurations`),
    view to view while the sphere stays put, then home. Each view is a stop of its own, so
    its error has its own share of the robot's repeatability (most of a calibrated cell's
    error): a position's views sample the error at a few seconds of robot time each where a
    new position costs the trip from home and back and the engineer's placement. `limit`:
    the accuracy limit in force with its basis (a maintenance keeps the commissioning's),
    else the one the commissioning will write (`accuracy_results`)."""
    cell = ctx.cell()
    c = cell.commission
    if positions is not None:
        c = dataclasses.replace(c, workspace_positions=positions)
    model, x = from_json(ctx.path(PARAMS_FILE))
    rigid = cell.model()
    x_rigid = x[: len(rigid.nominal_x())]
    rng = np.random.default_rng([c.seed, 31])
    proposed = workspace_points(cell, c.workspace_positions, rng)
    r = StepResult(files=[WORKSPACE_ERRORS_FILE])
    if ctx.station.tracker is None:
        r.checks.append(holds("a tracker for the validation sphere", False, "none in [devices]"))
        return r
    target = c.validation_target
    tracked: dict[str, F64] = {}
    views: list[tuple[str, Measurements]] = []
    sensor = ctx.sphere_sensor(ctx.sensor_model())
    T_base_part = np.linalg.inv(cell.T_part_base)
    try:
        for k, (name, p) in enumerate(proposed.items(), start=1):
            p_base = T_base_part[:3, :3] @ p + T_base_part[:3, 3]
            where = ", ".join(f"{v:.0f}" for v in p_base)
            ctx.place(target, p, f"position {k}/{len(proposed)} near ({where}) mm, base frame")
            p_tracker = ctx.station.tracker.measure(target).point_mm
            view = candidates.random_configurations(rigid, x_rigid, p_tracker, 1, rng)
            if not len(view.q_deg):
                ctx.say(f"    {name}: no reachable view; position skipped")
                continue
            qs = [view.q_deg[0]]
            if views_per_position > 1:
                near = candidates.neighbour_configurations(
                    rigid, x_rigid, p_tracker, qs[0], view.c_planned_mm[0],
                    views_per_position - 1, rng,
                )  # fmt: skip
                qs += list(near.q_deg)
            ctx.home()
            taken = measure_views(
                ctx, [(target, q) for q in qs], sensor, f"workspace {name}", via_home=False
            )
            if taken.rejected:
                r.results.setdefault("rejected", []).extend(taken.rejected)
            if not taken.targets:
                continue
            tracked[name] = p_tracker
            views.append((name, taken.data({target: p_tracker})))
    finally:
        ctx.remove(target)
    names = [n for n, _ in views]  # the positions measured, each from one view or more
    data = [d for _, d in views]
    r.checks.append(
        count_at_least(
            "positions measured",
            len(names),
            len(proposed),
            len(proposed) * (1 - c.max_rejected_fraction),
        )
    )
    if not names:
        return r
    q = np.concatenate([d.q_deg for d in data])
    cs = np.concatenate([d.c_sensor_mm for d in data])
    temps = [d.temp_c for d in data if d.temp_c is not None]
    temp = np.concatenate(temps) if len(temps) == len(data) else None
    p_sys = model.points_part(x, q, cs, temp_c=temp)
    counts = [len(v.q_deg) for v in data]
    p_ref = np.repeat(np.array([tracked[n] for n in names]), counts, axis=0)
    e = p_sys - p_ref
    d = np.linalg.norm(e, axis=1)
    view_names = [view_name(n, j) for n, k in zip(names, counts, strict=True) for j in range(k)]
    rows = [
        [n, *map(float, p_sys[i]), *map(float, e[i]), float(d[i])] for i, n in enumerate(view_names)
    ]
    write_csv(ctx.path(WORKSPACE_ERRORS_FILE), ERROR_COLUMNS, rows)
    by_position = position_norms_mm(view_names, list(d))
    lo, hi = rms_interval(np.array(by_position), np.random.default_rng([c.seed, 37]))
    r.results |= {
        "positions": len(proposed),
        "measured": len(names),
        "views": len(d),
        "rmse_mm": rmse(e),
        "rmse_95_interval_mm": [lo, hi],
    }
    # the commissioned cell's U95 for a point measured now: the upper 95 % bound from these
    # end-to-end errors (tracker against rvis: sensor, calibration and robot together, as a
    # body's point is measured; calib.uncertainty), one norm per position (its views share the
    # position's systematic share: counted as one, the bound errs on the safe side), and VDA
    # 5's 2U/T against the plant's tolerance when it is given
    u95 = u95_mm(by_position)
    r.results |= accuracy_results(u95, c.tolerance_mm, limit)
    if ctx.truth is not None:  # the simulated line: the end-to-end truth at its 100 positions
        r.results["true_rmse_mm"] = ctx.truth.true_rmse_mm(model, x, ctx.sensor_model())
    # the error's figures with the check, in mm to 0.1 um; only the RMS has a limit
    worst = view_names[int(np.argmax(d))]
    r.checks += [
        at_most("workspace RMSE", rmse(e), c.max_workspace_rmse_mm, "mm", fmt=MM),
        stated("workspace error, mean", float(d.mean()), "mm", MM),
        stated(f"workspace error, largest ({worst})", float(d.max()), "mm", MM),
        stated("workspace error, 95th percentile", float(np.percentile(d, 95)), "mm", MM),
    ]
    if c.tolerance_mm > 0:
        r.checks.append(
            ratio_at_most(
                "VDA 5 capability 2 U95 / T", 2.0 * u95, c.tolerance_mm, VDA5_MAX_RATIO, "mm"
            )
        )
    return r
