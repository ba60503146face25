"""A step of the cell (a knock) from its flag to its correction: what moved, the fast correction
of that group, the suspect interval, and the slots measured meanwhile.

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

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from enum import StrEnum
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
#: E|d| of a 3-D normal difference d with per-coordinate sigma: sigma sqrt(8 / pi)
_MEAN_NORM_3D = float(np.sqrt(8.0 / np.pi))
RECENT_FIRST = 2  # slots measured just before the change point revisited first
#: a refinement's held-out change within the noise: sqrt(chi-square 3 dof, p = 0.99) sigma
HELD_OUT_NOISE = float(np.sqrt(11.345))


class StepStatus(StrEnum):
    """Where a flagged step is in its life (the `Step` docstring says what each means)."""

    PROBATION = "probation"
    ATTRIBUTING = "attributing"
    PROPOSED = "proposed"
    REFINING = "refining"
    FOLLOWING = "following"
    RECOVERING = "recovering"
    CORRECTED = "corrected"
    SEVERAL = "several"
    NONE = "none"


_S = StepStatus
#: the moves a step may make (`Step.move`); a step is born on probation, or "several" when it
#: cannot be attributed; it leaves the service's decision state after a full recalibration
#: trained after it (or dropped as drift from probation)
TRANSITIONS: dict[StepStatus, frozenset[StepStatus]] = {
    _S.PROBATION: frozenset({_S.ATTRIBUTING}),
    _S.ATTRIBUTING: frozenset({_S.PROPOSED, _S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING}),
    _S.PROPOSED: frozenset({_S.ATTRIBUTING, _S.REFINING, _S.RECOVERING}),
    _S.REFINING: frozenset({_S.RECOVERING, _S.CORRECTED}),
    _S.FOLLOWING: frozenset({_S.FOLLOWING, _S.SEVERAL, _S.NONE, _S.RECOVERING}),
    _S.RECOVERING: frozenset({_S.RECOVERING, _S.CORRECTED}),
    _S.CORRECTED: frozenset({_S.RECOVERING}),
    _S.SEVERAL: frozenset({_S.SEVERAL, _S.RECOVERING, _S.FOLLOWING}),
    _S.NONE: frozenset({_S.NONE}),
}
#: the statuses in which the windows measure for the step (more slots, chosen for it)
MEASURING = frozenset({_S.PROBATION, _S.ATTRIBUTING, _S.FOLLOWING, _S.REFINING, _S.RECOVERING})


@dataclass
class Step:
    """The step in progress (part of the service's decision state). `status`: probation
    (flagged, not confirmed: a step or drift? no suspect interval yet), attributing
    (no correction yet), proposed (a correction waits for approval), refining (the first
    correction applied, one more window of measurements refines it), following (sequential
    estimator: the suspected group's covariance widened, its candidate awaited), corrected
    (applied; the full recalibration on post-step measurements follows), several (no single
    group: waiting for the full recalibration), none (no step found)."""

    onset_id: int
    suspect_id: int | None  # None while on probation
    t_start: float
    last_good_id: int | None
    status: StepStatus = StepStatus.ATTRIBUTING
    choice: str | None = None
    text: str = ""
    n_used: int = 0  # measurements the last attribution used
    flag_id: int | None = None  # the measurement whose chart signalled
    start_id: int | None = None  # the first measurement after the step, as located
    n_corrected: int = 0  # measurements when the first correction was made
    refine_mm: float | None = None  # how far the refinement moved points at the standoff
    refine_tries: int = 0
    signal: str = ""  # what the drift charts saw (the high alarm's text once confirmed)
    base_version: int | None = None  # the parameters the first correction was computed from
    # recovering (a correction trained after the step is in force; the interval stays open
    # until the held-out residuals measured with it are back at the level before the step)
    recover_version: int | None = None  # the correction under test
    recover_t: float | None = None  # when it went in force (where the interval ends if back)
    recover_cal_id: int | None = None
    recover_kind: str | None = None  # "step" | "batch" | "sequential"
    recover_from_id: int = 0  # its held-out measurements are the ones after this id
    level_mm: float | None = None  # held-out residual RMS before the step
    level_n: int = 0
    full_recals: int = 0  # full recalibrations applied since the step
    recovery: str = ""  # the last recovery test, in words
    recover_n: int = 0  # measurements the last recovery test used
    change_from_before: int = 0  # the service's change_from_id before the flag (a drop restores)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(doc: Mapping[str, Any] | None) -> Step | None:
        if doc is None:
            return None
        known = {f.name for f in fields(Step)}  # a state saved by an older version: its fields
        step = Step(**{k: v for k, v in doc.items() if k in known})
        step.status = StepStatus(step.status)
        return step

    @property
    def measuring(self) -> bool:
        """The schedule serves the attribution (more slots per window, chosen for it)."""
        return self.status in MEASURING

    def move(self, to: StepStatus | str) -> None:
        """Change the status along an allowed transition (`TRANSITIONS`; ValueError else)."""
        new = StepStatus(to)
        if new not in TRANSITIONS[self.status]:
            raise ValueError(f"a step cannot go from {self.status} to {new}")
        self.status = new


def step_alarm_text(signal: str, attribution: str = "") -> str:
    """The high `drift_step` alarm's message: what the drift charts saw (`signal`) and, once
    attributed, what moved (`attribution`, the attribution's text). The one place it is built;
    the parts themselves are kept as data (`Step.signal`, the suspect interval's text)."""
    head = (
        f"{signal}: check the cell (sensor mount, spheres); recalibrating on the measurements"
        " after it"
    )
    return f"{head} | {attribution}" if attribution else head


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


MIN_SIGMA_PAIRS = 8  # consecutive visits of a slot before the step that set sigma


@dataclass(frozen=True)
class Recovery:
    """Are the held-out residuals after a correction back at their level before the step?
    `verdict`: "back" (not higher at the stated confidence), "higher" (higher at it) or
    "undetermined" (too few measurements after the correction yet)."""

    verdict: str
    rms_after_mm: float
    n_after: int
    rms_before_mm: float
    n_before: int
    ratio_f: float  # (rms_after / rms_before)^2
    limit_f: float  # the F quantile it is held to (inf while undetermined)
    confidence: float

    @property
    def text(self) -> str:
        head = (
            f"held-out RMS {self.rms_after_mm:.4f} mm on {self.n_after} measurements after the"
            f" correction, {self.rms_before_mm:.4f} mm on {self.n_before} before the step"
        )
        if self.verdict == "undetermined":
            return f"{head}: too few to judge yet"
        word = "higher" if self.verdict == "higher" else "not higher"
        return (
            f"{head}: {word} at {self.confidence:.0%} confidence"
            f" (F {self.ratio_f:.2f} {'>' if self.verdict == 'higher' else '<='}"
            f" {self.limit_f:.2f})"
        )

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "text": self.text}


def recovery_test(
    before_mm: Sequence[float], after_mm: Sequence[float], confidence: float, min_after: int
) -> Recovery:
    """One-sided F test of the held-out residuals `after_mm` (norms [mm] of measurements taken
    with the correction in force, none of them used to compute it) against `before_mm` (those
    of the in-control measurements just before the step): each norm^2 carries 3 degrees of
    freedom. "higher" when (RMS after / RMS before)^2 exceeds the F(3 n_after, 3 n_before)
    quantile at `confidence`; "back" when not and at least `min_after` were measured."""
    from scipy.stats import f as f_dist

    a = np.asarray(after_mm, dtype=float)
    b = np.asarray(before_mm, dtype=float)
    rms_a = float(np.sqrt(np.mean(a**2))) if len(a) else float("nan")
    rms_b = float(np.sqrt(np.mean(b**2))) if len(b) else float("nan")
    if len(a) == 0 or len(b) == 0 or not rms_b > 0:
        return Recovery(
            "undetermined", rms_a, len(a), rms_b, len(b), float("nan"), math.inf, confidence
        )
    ratio = (rms_a / rms_b) ** 2
    limit = float(f_dist.ppf(confidence, 3 * len(a), 3 * len(b)))
    if ratio > limit:
        verdict = "higher"
    elif len(a) >= min_after:
        verdict = "back"
    else:
        verdict, limit = "undetermined", math.inf
    return Recovery(verdict, rms_a, len(a), rms_b, len(b), ratio, limit, confidence)


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
    last: dict[int, Mapping[str, Any]] = {}
    for r in before:
        last[int(r["slot"])] = r
    out = []
    for r in after:
        ref = last.get(int(r["slot"]))
        if ref is not None and np.allclose(ref["q_deg"], r["q_deg"], atol=1e-6):
            out.append((r, ref))
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
    pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]],
    spheres: Mapping[str, F64],
    sigma_mm: float,
    views: tuple[F64, F64],
    settings: RecalibSettings,
    gates: Gates,
    *,
    groups: Sequence[StepGroup] | None = None,
    refine: bool = False,
    x_in_force: F64 | None = None,
) -> tuple[Attribution, StepCorrection | None]:
    """Attribute the step on all pairs but the newest and gate the chosen group's correction
    (module docstring). `views`: configurations (N, 6) with points (N, 3) in the sensor frame
    where the correction's uncertainty is predicted (`volume_views`). The correction is None when no
    single group was chosen. `refine`: a correction already applied is refined (`groups`:
    nothing or its group; x_current: the parameters the first correction was computed from,
    as the pairs' differences restore the state before the step relative to them;
    `x_in_force`: the first correction, which the held-out check and the change bounds are
    against): no BIC margin is asked for, and the held-out measurement need only be
    predicted within the noise (chi-square, 3 dof, p = 0.99) when not better."""
    x_force = x_current if x_in_force is None else x_in_force
    rows = [p[0] for p in pairs]
    ref = reference_mm(model, x_current, [p[1] for p in pairs], spheres)
    data = as_measurements(rows, spheres)
    fit_rows = np.arange(len(rows) - 1)
    a = attribute(
        model,
        x_current,
        data.subset(fit_rows),
        sigma_mm=sigma_mm,
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
    if not std <= settings.step_max_std_mm:
        failures.append(f"predicted uncertainty {std:.4f} mm > {settings.step_max_std_mm:g} mm")
    newest = data.subset([len(rows) - 1])
    cand = float(np.linalg.norm(residuals(model, fit.x, newest)[0] - ref[-1]))
    cur = float(np.linalg.norm(residuals(model, x_force, newest)[0] - ref[-1]))
    noise = HELD_OUT_NOISE * sigma_mm if refine else 0.0
    ratio = 1.0 if gates.max_holdout_ratio is None else gates.max_holdout_ratio
    if not cand <= max(ratio * cur, noise):
        failures.append(
            f"held-out change {cand:.4f} mm not better than the parameters in force ({cur:.4f} mm)"
        )
    failures += change_failures(fit.group.params, fit.x, x_force, gates)
    doc = plain_document(model, fit.x, f"rvis run (step correction: {a.text()})")
    doc["estimator"] = {"kind": "step", "group": fit.group.name, "attribution": a.to_json()}
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
