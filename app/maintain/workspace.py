"""The workspace validation of a maintenance procedure: the commissioning's step at the
maintenance's positions, stated against the limit in force and compared with the version
before (app/maintain/__init__.py)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.commission.checks import Check, StepResult
from app.commission.context import Context
from app.commission.files import PARAMS_BEFORE_FILE, WORKSPACE_ERRORS_FILE
from app.commission.workspace import workspace_evidence_mm
from app.formats.files import read_json
from calib.uncertainty import larger_rms_bound, shown_larger_than

#: why the workspace validation does not run without a tracker
NO_TRACKER = (
    "no tracker at hand: the cell's accuracy after the procedure is not validated against an"
    " independent reference (the accuracy statement's floor stays the commissioning's workspace"
    " validation); measure the spheres with a tracker when one is at hand (`rvis maintain"
    " fixture --targets FILE`)"
)


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
        r.results |= {"workspace_rmse_before_mm": rms_mm(before), "workspace_change": text}
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
    a, b = rms_mm(list(after_mm)), rms_mm(list(before_mm))
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


def rms_mm(errors: list[float]) -> float | None:
    """The RMS of error norms [mm] (None for none)."""
    return float(np.sqrt(np.mean(np.square(errors)))) if errors else None
