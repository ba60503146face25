"""The numbers of a step (a knock) from its flag to its correction: what moved, the fast
correction of that group and its gates, and the slot to measure meanwhile (the record of the
step and its suspect interval: app.line.step).

When the drift charts flag a step (app.line.drift, change point `onset_id`), the service opens a
`Step` and a suspect interval: from the last trustworthy measurement before the change point on,
the calibration in force may be wrong, and the bodies measured then may need measuring again.
After every window (`correct_step`) the measurements from the change point on are paired with
the last visit of the same slot before it (their residuals with the parameters in force are the
reference: the calibration error that was there before the step is not the step), and
calib.attribution fits each candidate group on all but the newest. The choice becomes a fast
correction (the parameters in force with that group replaced) when its gates pass:

    decisive       BIC margin over the runner-up >= step_min_margin, a single group that
                   explains the step (chi2 plausible; not "several", not "none")
    bounded cov    its predicted uncertainty over the measuring volume at the schedule's
                   configurations <= step_max_std_mm
    held out       the newest measurement, not fitted, is predicted better than by the
                   parameters in force (ratio <= max_holdout_ratio)
    bounded change every parameter of the group within the in-line change bounds

It is applied (auto) or proposed (approve) like any calibration. The suspect interval then stays
open until the held-out residuals measured with the correction in force are back at their level
before the step (`recovery_test`, app.line.step_handler.StepHandler.check_recovery); meanwhile the
full recalibration on post-step measurements runs as soon as they span half the schedule.
Until the interval closes the schedule measures up to `step_slots_per_window` slots per window
that fit its time budget: first the configurations measured just before the change point (freshest
references), then the one most informative for the candidate groups (`step_slot`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config.line import RecalibSettings
from app.formats.params import plain_document
from app.line.recalib import as_measurements
from app.line.schedule import Slot
from calib.attribution import (
    NONE,
    SEVERAL,
    Attribution,
    StepGroup,
    attribute,
    predicted_std_mm,
    step_groups,
)
from calib.gate_limits import Gates
from calib.gates import change_failures
from calib.identify import residuals
from calib.model import SystemModel

F64 = NDArray[np.float64]
#: measurements before a flagged step that its attribution needs as references (a knock in a
#: new cell's first schedule cycle is attributed on the slots measured before it: the windows
#: measure them again, `step_slot`)
MIN_STEP_REFS = 3
#: E|d| of a 3-D normal difference d with per-coordinate sigma: sigma sqrt(8 / pi)
_MEAN_NORM_3D = float(np.sqrt(8.0 / np.pi))
RECENT_FIRST = 2  # slots measured just before the change point revisited first
#: a refinement's held-out change within the noise: sqrt(chi-square 3 dof, p = 0.99) sigma
HELD_OUT_NOISE = float(np.sqrt(11.345))


@dataclass(frozen=True, eq=False)
class StepCorrection:
    """A fast correction to gate and apply: the fields the service stores for a calibration."""

    passed: bool
    failures: tuple[str, ...]
    document: dict[str, Any]
    rms_mm: float  # of the fitted measurements against their references
    holdout_rms_mm: float
    current_holdout_rms_mm: float
    n_measurements: int
    first_id: int
    last_id: int


SQRT3 = float(np.sqrt(3.0))  # a 3-D RMS over one coordinate's
MIN_SIGMA_PAIRS = 8  # consecutive visits of a slot before the step that set sigma


def volume_points_mm(volume_mm: Sequence[float]) -> F64:
    """Points (7, 3) [mm, sensor frame] that span the measuring volume (standoff, half field of
    view x and y, half depth): its centre, the four corners of the field of view at 0.8 of its
    half widths, and the centre at the near and far depth."""
    s, hx, hy, hd = (float(v) for v in volume_mm)
    corners = [[sx * 0.8 * hx, sy * 0.8 * hy, s] for sx in (-1, 1) for sy in (-1, 1)]
    return np.array([[0.0, 0.0, s], *corners, [0.0, 0.0, s - hd], [0.0, 0.0, s + hd]])


def volume_views(q_deg: F64, volume_mm: Sequence[float]) -> tuple[F64, F64]:
    """Every configuration (K, 6) with every point of the measuring volume: (K*7, 6), (K*7, 3)
    (where a correction's uncertainty is predicted: a sensor's tilt that the spheres near the
    middle of the field of view do not show moves the points at its edges)."""
    pts = volume_points_mm(volume_mm)
    q = np.asarray(q_deg, dtype=float).reshape(-1, 6)
    return np.repeat(q, len(pts), axis=0), np.tile(pts, (len(q), 1))


def step_sigma_mm(
    before: Sequence[Mapping[str, Any]],
    change_mu_mm: float | None,
    measurement_std_mm: float,
    residuals_mm: F64 | None = None,
) -> float:
    """One coordinate's standard deviation of a measurement minus its pre-step reference, as
    the attribution's pairs have it (noise and the drift over about a schedule cycle): from the
    mean |c_t - c_prev| of consecutive visits of the same slot in the rows `before` the step
    when there are at least MIN_SIGMA_PAIRS (recent: the warm-up's drift is that of now), else
    the change charts' baseline mean (learned once), else sqrt(2) x one measurement's; for a
    3-D normal difference E|d| = sigma sqrt(8 / pi). `residuals_mm` (n, 3), the rows' residuals
    with the parameters in force: the differences are taken on them instead of on the raw
    centres, so that the drift the model predicts (the compliant model's thermal term in the
    warm-up) is not counted as noise, as the attribution's pairs do not count it."""
    last: dict[int, tuple[Mapping[str, Any], Any]] = {}
    d = []
    for k, r in enumerate(before):
        v = r["c_sensor_mm"] if residuals_mm is None else residuals_mm[k]
        prev = last.get(int(r["slot"]))
        if prev is not None and np.allclose(prev[0]["q_deg"], r["q_deg"], atol=1e-6):
            d.append(float(np.linalg.norm(np.subtract(v, prev[1]))))
        last[int(r["slot"])] = (r, v)
    if len(d) >= MIN_SIGMA_PAIRS:
        return float(np.mean(d)) / _MEAN_NORM_3D
    if change_mu_mm is not None and change_mu_mm > 0:
        return change_mu_mm / _MEAN_NORM_3D
    return float(np.sqrt(2.0) * measurement_std_mm)


def paired(
    after: Sequence[Mapping[str, Any]], before: Sequence[Mapping[str, Any]]
) -> list[tuple[Mapping[str, Any], Mapping[str, Any]]]:
    """(row after the change point, the last row of the same slot and configuration before it)
    for every row after it that has one, in id order."""
    return [(r, ref) for r, ref in with_references(after, before) if ref is not None]


def with_references(
    after: Sequence[Mapping[str, Any]], before: Sequence[Mapping[str, Any]]
) -> list[tuple[Mapping[str, Any], Mapping[str, Any] | None]]:
    """(row after the change point, its reference: the last row of the same slot and
    configuration before it, or None) for every row after it, in id order."""
    last: dict[int, Mapping[str, Any]] = {}
    for r in before:
        last[int(r["slot"])] = r
    out: list[tuple[Mapping[str, Any], Mapping[str, Any] | None]] = []
    for r in after:
        ref = last.get(int(r["slot"]))
        same = ref is not None and np.allclose(ref["q_deg"], r["q_deg"], atol=1e-6)
        out.append((r, ref if same else None))
    return out


def reference_mm(
    model: SystemModel, x: F64, refs: Sequence[Mapping[str, Any]], spheres: Mapping[str, F64]
) -> F64:
    """The residuals (n, 3) [mm] of the pre-step rows with the parameters x."""
    out: F64 = residuals(model, x, as_measurements(refs, spheres))
    return out


def visible_step_mm(a: Attribution) -> float:
    """How big the step looks, noise removed: the RMS over the pairs of |after - before| [mm]
    (from the "nothing moved" fit's chi2) less the 3-D noise of a difference, 3 sigma^2."""
    none = a.fit(NONE)
    if not none.determined or a.n == 0:
        return 0.0
    excess = none.chi2 * a.sigma_mm**2 / a.n - 3.0 * a.sigma_mm**2
    return float(np.sqrt(max(excess, 0.0)))


def locate_step(
    model: SystemModel,
    x: F64,
    pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]],
    spheres: Mapping[str, F64],
    sigma_mm: float,
    flag_id: int | None,
) -> int:
    """Where the step happened among the pairs up to the flagging measurement (the CUSUM's
    change point estimate can be a few samples early, before a signal it grew slowly towards,
    or late, when the first sample after the step did not reach its chart): the split s that
    minimises chi2 of "nothing moved" on pairs[:s] plus the best single group's BIC on
    pairs[s:], every pair against a reference from before pairs[0]. The index s."""
    # up to the first pair after the flagging measurement: the step may lie just before a
    # measurement that has no reference (a slot not measured before) and so no pair
    last = (
        len(pairs) - 1
        if flag_id is None
        else next((i for i, (r, _) in enumerate(pairs) if int(r["id"]) > flag_id), len(pairs) - 1)
    )
    candidates = [i for i in range(min(last, len(pairs) - 2) + 1)]
    if len(candidates) <= 1:
        return 0
    ref = reference_mm(model, x, [p[1] for p in pairs], spheres)
    data = as_measurements([p[0] for p in pairs], spheres)
    e = np.sum(((residuals(model, x, data) - ref) / sigma_mm) ** 2, axis=1)
    scores = []
    for i in candidates:
        rows = np.arange(i, len(pairs))
        a = attribute(model, x, data.subset(rows), sigma_mm=sigma_mm, reference_mm=ref[rows])
        best = min(f.bic for f in a.fits if f.determined and f.group.name != SEVERAL)
        scores.append(float(np.sum(e[:i])) + best)
    return candidates[int(np.argmin(scores))]


def correct_step(
    model: SystemModel,
    x_current: F64,
    pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any] | None]],
    spheres: Mapping[str, F64],
    sigma_mm: float,
    views: tuple[F64, F64],
    settings: RecalibSettings,
    gates: Gates,
    *,
    groups: Sequence[StepGroup] | None = None,
    refine: bool = False,
    x_in_force: F64 | None = None,
    absolute_sigma_mm: float | None = None,
) -> tuple[Attribution, StepCorrection | None]:
    """Attribute the step on all pairs but the newest and gate the chosen group's correction
    (module docstring). `views`: configurations (N, 6) with points (N, 3) in the sensor frame
    where the correction's uncertainty is predicted (`volume_views`). The correction is None when no
    single group was chosen. `refine`: a correction already applied is refined (`groups`:
    nothing or its group; x_current: the parameters the first correction was computed from,
    as the pairs' differences restore the state before the step relative to them;
    `x_in_force`: the first correction, which the held-out check and the change bounds are
    against): no BIC margin is asked for, and the held-out measurement need only be
    predicted within the noise (chi-square, 3 dof, p = 0.99) when not better. A row with no
    reference (None: its slot was not measured before the step, a new cell's) is fitted on its
    residual itself, with `absolute_sigma_mm` (the cell's level before the step: its
    calibration error there is unknown) for sigma."""
    x_force = x_current if x_in_force is None else x_in_force
    rows = [p[0] for p in pairs]
    have = [k for k, p in enumerate(pairs) if p[1] is not None]
    refs = [p[1] for p in pairs if p[1] is not None]
    ref = np.zeros((len(rows), 3))
    if have:
        ref[have] = reference_mm(model, x_current, refs, spheres)
    sigma = np.full(len(rows), sigma_mm if absolute_sigma_mm is None else absolute_sigma_mm)
    sigma[have] = sigma_mm
    data = as_measurements(rows, spheres)
    fit_rows = np.arange(len(rows) - 1)
    a = attribute(
        model,
        x_current,
        data.subset(fit_rows),
        sigma_mm=sigma[fit_rows],
        reference_mm=ref[fit_rows],
        groups=groups,
    )
    fit = a.chosen
    if a.choice in (NONE, SEVERAL) or fit is None:
        return a, None
    failures = []
    if not refine and a.margin < settings.step_min_margin:
        other = a.runner_up
        failures.append(
            f"not decisive: BIC margin {a.margin:.1f} over"
            f" {other.group.label if other else '-'} < {settings.step_min_margin:g}"
        )
    if not fit.consistent:
        failures.append(f"chi2 {fit.chi2:.1f} too large for {fit.dof} degrees of freedom")
    std = predicted_std_mm(model, fit, views[0], views[1])
    # bounded absolutely, or, for a step large beside it, by the step: a correction that
    # removes most of a large step is taken while it is not yet fine (refined as more come)
    bound = max(settings.step_max_std_mm, settings.step_std_fraction * visible_step_mm(a) / SQRT3)
    if not std <= bound:
        failures.append(f"predicted uncertainty {std:.4f} mm > {bound:.4g} mm")
    newest = data.subset([len(rows) - 1])
    cand = float(np.linalg.norm(residuals(model, fit.x, newest)[0] - ref[-1]))
    cur = float(np.linalg.norm(residuals(model, x_force, newest)[0] - ref[-1]))
    noise = HELD_OUT_NOISE * float(sigma[-1]) if refine else 0.0
    ratio = 1.0 if gates.max_holdout_ratio is None else gates.max_holdout_ratio
    if not cand <= max(ratio * cur, noise):
        failures.append(
            f"held-out change {cand:.4f} mm not better than the parameters in force ({cur:.4f} mm)"
        )
    failures += change_failures(fit.group.params, fit.x, x_force, gates)
    doc = plain_document(model, fit.x, f"rvis run (step correction: {a.text()})")
    doc["estimator"] = {
        "kind": "step",
        "group": fit.group.name,
        "attribution": a.to_json(),
        "predicted_std_mm": float(std) if np.isfinite(std) else None,  # per coordinate
    }
    doc["success"] = not failures
    fitted = ref[fit_rows] - residuals(model, fit.x, data.subset(fit_rows))
    correction = StepCorrection(
        not failures,
        tuple(failures),
        doc,
        float(np.sqrt(np.mean(np.sum(fitted**2, axis=1)))),
        cand,
        cur,
        len(rows) - 1,
        int(rows[0]["id"]),
        int(rows[-1]["id"]),
    )
    return a, correction


def step_slot(
    model: SystemModel,
    x: F64,
    pool: Sequence[Slot],
    after: Sequence[Mapping[str, Any]],
    recent_before: Sequence[int],
    seen: Mapping[int, tuple[F64, F64]],
    groups: Sequence[StepGroup] | None = None,
    where: tuple[F64, F64] | None = None,
) -> Slot:
    """The slot to measure next while a step is attributed, of those that fit (`pool`, in the
    plan's order): a slot measured just before the change point not measured again yet (most
    recent first, `recent_before`), else the one after which the candidate groups (`groups`,
    default every single group) predict the points `where` (configurations, sensor-frame
    points: the measuring volume at the schedule's configurations; default the slots' own
    centres) best: the least sum over the groups of trace(cov H^T H), with the rows measured
    since the change point, `after` (I-optimal). `seen`: slot -> (q, last centre)."""
    done = {int(r["slot"]) for r in after}
    fresh = [s for s in pool if s.index not in done] or list(pool)
    for index in recent_before[:RECENT_FIRST]:
        for s in fresh:
            if s.index == index and index not in done:
                return s
    candidates = [s for s in fresh if s.index in seen]
    if not candidates:
        return fresh[0]
    if groups is None:
        groups = [g for g in step_groups(model) if g.name not in (NONE, SEVERAL)]
    names = tuple(dict.fromkeys(p for g in groups for p in g.params))
    q_have = np.array([r["q_deg"] for r in after]).reshape(-1, 6)
    c_have = np.array([r["c_sensor_mm"] for r in after]).reshape(-1, 3)
    J_have = model.point_jacobian(x, q_have, c_have, names).reshape(-1, len(names))
    q = np.array([s.q_deg for s in candidates])
    c = np.array([seen[s.index][1] for s in candidates])
    J_new = model.point_jacobian(x, q, c, names)  # (K, 3, L)
    q_at, c_at = where if where is not None else (q, c)
    H = model.point_jacobian(x, q_at, c_at, names).reshape(-1, len(names))
    cols = {n: k for k, n in enumerate(names)}
    score = np.zeros(len(candidates))
    for g in groups:
        idx = [cols[p] for p in g.params]
        A = J_have[:, idx].T @ J_have[:, idx]
        M = H[:, idx].T @ H[:, idx]
        for k in range(len(candidates)):
            B = A + J_new[k][:, idx].T @ J_new[k][:, idx]
            ridge = 1e-9 * max(float(np.trace(B)) / len(idx), 1e-12)
            score[k] -= float(np.trace(np.linalg.pinv(B + ridge * np.eye(len(idx))) @ M))
    return candidates[int(np.argmax(score))]
