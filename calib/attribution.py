"""Step attribution: which rigid group of the chain moved, from a few measurements after a step.

A knock usually moves one rigid group of the chain part <- base <- joints <- flange <- sensor:
the sensor on its mount (the 6 flange->sensor parameters), the sphere fixture or the part frame
(the 6 part->base parameters), or one joint's zero (one offset, `dtheta2`..`dtheta5`; the J1 and
J6 zeros are absorbed by the base and the sensor). Each candidate group is fitted on the
measurements from the change point on with everything else held at the parameters in force
`x_ref`; the groups are compared by the Bayesian information criterion

    BIC_g = chi2_g + k_g ln(3 n)        chi2_g = sum_i |r_i(x_g) - r_ref,i|^2 / sigma_i^2

(k_g parameters, n measurements of 3 coordinates each, sigma_i the standard deviation of one
coordinate of measurement i). `reference_mm` (n, 3), when given, is each measurement's residual
before the step at the same configuration (the last visit of the same slot, mapped with the same
`x_ref`): the fit then restores the pre-step residual pattern instead of chasing the calibration
error that was already there, and sigma is that of a difference of two measurements. The choice:
the determined single group with the lowest BIC, unless its chi2 is implausible for its degrees
of freedom (chi-square quantile `p_consistent`) or the full set ("several", fitted only when
3 n > its size) has a lower BIC: then no single group explains the step and the caller waits for
a full recalibration. The evidence: each group's chi2, BIC and the standard uncertainties of its
step (sigma^2-scaled (J^T J)^-1), the margin of the choice over the runner-up.

Pure numerics: nothing here knows the service; app/line/ decides what to do with the choice.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.errors import InsufficientData
from calib.identify import Measurements
from calib.model import BASE_NAMES, INDEX, SENSOR_NAMES, SystemModel, check_active, unit_of
from calib.uncertainty import chi2_ppf

F64 = NDArray[np.float64]
SEVERAL = "several"
NONE = "none"
#: p of the chi-square quantile a single group's fit must stay below to explain the step
P_CONSISTENT = 0.999


@dataclass(frozen=True)
class StepGroup:
    """A candidate of what moved: `name` (machine), `label` (for people), its parameters."""

    name: str
    label: str
    params: tuple[str, ...]


#: the J2 motor or encoder replaced: a zero moved on the controller's J2 moves, through the
#: J2/J3 coupling, the forearm's angle to the upper arm with it (theta2 and theta3,
#: calib/robot.py). Beyond a knock only (`maintenance_groups`): among the knocks' groups its
#: spare parameter would let noise pick it over J2's zero alone.
J2_ENCODER = StepGroup("J2-encoder", "J2 encoder zero (J3 coupled)", ("dtheta2", "dtheta3"))


def step_groups(model: SystemModel) -> tuple[StepGroup, ...]:
    """The candidates of a model: nothing moved ("none": the parameters in force explain the
    measurements), sensor mount, sphere fixture / part frame, each identified joint zero
    offset, and the full set the model identifies ("several")."""
    active = model.default_active()
    joints = [n for n in active if n.startswith("dtheta")]
    return (
        StepGroup(NONE, "nothing", ()),
        StepGroup("sensor", "sensor mount", SENSOR_NAMES),
        StepGroup("fixture", "sphere fixture / part frame", BASE_NAMES),
        *(StepGroup(f"J{n[-1]}", f"J{n[-1]} zero", (n,)) for n in joints),
        StepGroup(SEVERAL, "several groups", tuple(active)),
    )


def maintenance_groups(model: SystemModel) -> tuple[StepGroup, ...]:
    """The candidates of a change beyond a knock: the knocks' (`step_groups`) and J2's
    encoder zero where the model identifies theta2 and theta3."""
    groups = step_groups(model)
    if not set(J2_ENCODER.params) <= set(model.default_active()):
        return groups
    return (*groups[:-1], J2_ENCODER, groups[-1])


@dataclass(frozen=True)
class GroupFit:
    """One group fitted with everything else held. `x` full vector; `step` (k,) the change of
    the group's parameters from x_ref [mm, rad], `std` (k,) their standard uncertainties and
    `cov` (k, k) the covariance; chi2 at the fit with `dof` = 3 n - k; `determined`: enough
    equations and full column rank (otherwise chi2 and bic are inf)."""

    group: StepGroup
    x: F64
    step: F64
    std: F64
    cov: F64
    chi2: float
    dof: int
    bic: float
    determined: bool
    shift_mm: float = float("nan")  # RMS move of the measured centres, x_ref -> x [mm]

    @property
    def translation_mm(self) -> float:
        """|translation| of a 6-DoF group's step (0 for a joint offset or nothing)."""
        mm = [k for k, n in enumerate(self.group.params) if unit_of(n) == "mm"]
        return float(np.linalg.norm(self.step[mm])) if len(self.group.params) == 6 else 0.0

    @property
    def rotation_deg(self) -> float:
        """Rotation angle of a 6-DoF group's step, or |offset| of a joint zero [deg]."""
        rad = [k for k, n in enumerate(self.group.params) if unit_of(n) == "rad"]
        return float(np.degrees(np.linalg.norm(self.step[rad])))

    @property
    def consistent(self) -> bool:
        """chi2 plausible for dof (an exact fit, dof 0, cannot be tested: True)."""
        if not self.determined:
            return False
        return self.dof == 0 or self.chi2 <= chi2_ppf(P_CONSISTENT, self.dof)

    def size_text(self) -> str:
        """The step in its own terms, then where it matters: how far it moves the measured
        centres (a sensor's tilt and shift are confounded by centres near one point of the field
        of view; their effect there is not)."""
        at = f" ({self.shift_mm:.2f} mm at the measured spheres)"
        if len(self.group.params) == 6:
            return f"{self.translation_mm:.2f} mm / {self.rotation_deg:.3f} deg{at}"
        if len(self.group.params) == 1:
            return f"{self.rotation_deg:.4f} deg{at}"
        if 0 < len(self.group.params) <= 2 and all(unit_of(n) == "rad" for n in self.group.params):
            pairs = zip(self.group.params, self.step, strict=True)
            each = ", ".join(f"{n} {np.degrees(v):+.4f} deg" for n, v in pairs)
            return f"{each}{at}"
        return f"{len(self.group.params)} parameters{at}"

    def to_json(self) -> dict[str, object]:
        return {
            "group": self.group.name,
            "label": self.group.label,
            "params": list(self.group.params),
            "step": self.step.tolist() if self.determined else None,
            "std": self.std.tolist() if self.determined else None,
            "translation_mm": self.translation_mm if self.determined else None,
            "rotation_deg": self.rotation_deg if self.determined else None,
            "shift_mm": self.shift_mm if self.determined else None,
            "chi2": self.chi2 if self.determined else None,
            "dof": self.dof,
            "bic": self.bic if self.determined else None,
            "determined": self.determined,
        }


def likelihood_words(margin: float) -> str:
    """The BIC margin of the choice over the runner-up in words an operator reads (the figure
    itself stays in `Attribution.to_json`'s `margin`), on Kass and Raftery's scale of 2 ln K
    (1995): above 10 very strong evidence, 6-10 strong, 2-6 positive, below 2 not worth more
    than a mention."""
    if margin > 10:
        return "far less likely"
    if margin > 6:
        return "much less likely"
    if margin > 2:
        return "less likely"
    return "about as likely"


@dataclass(frozen=True)
class Attribution:
    """The candidates' fits (lowest BIC first, undetermined last), the `choice` (a group name
    or "several"), the chosen fit (None for "several" unless the full set was fitted), the BIC
    `margin` of the choice over the runner-up (inf when alone), n measurements, sigma [mm]."""

    fits: tuple[GroupFit, ...]
    choice: str
    chosen: GroupFit | None
    margin: float
    n: int
    sigma_mm: float

    def fit(self, name: str) -> GroupFit:
        return next(f for f in self.fits if f.group.name == name)

    @property
    def runner_up(self) -> GroupFit | None:
        c = self.chosen
        rest = [
            f
            for f in self.fits
            if f.determined
            and f.group.name != self.choice
            and (c is None or self.choice == SEVERAL or _rival(f, c))
        ]
        return rest[0] if rest else None

    def text(self) -> str:
        """One line for an alarm: "sensor mount moved 0.31 mm / 0.050 deg, 3 measurements;
        part frame far less likely" (the BIC margin in words: `likelihood_words`)."""
        n = f"{self.n} measurement{'s' * (self.n != 1)}"
        c = self.chosen
        if self.choice == NONE:
            return f"no step found: the parameters in force explain the {n} after it"
        if c is None or self.choice == SEVERAL:
            best = next((f for f in self.fits if f.determined and f.group.name != SEVERAL), None)
            why = "" if best is None else f" (best single: {best.group.label}, chi2 {best.chi2:.0f}"
            why += "" if best is None else f"/{best.dof})"
            return f"several groups moved{why}, {n}: waiting for the full recalibration"
        other = self.runner_up
        vs = "" if other is None else f"; {other.group.label} {likelihood_words(self.margin)}"
        return f"{c.group.label} moved {c.size_text()}, {n}{vs}"

    def to_json(self) -> dict[str, object]:
        return {
            "choice": self.choice,
            "text": self.text(),
            "margin": self.margin if np.isfinite(self.margin) else None,
            "n": self.n,
            "sigma_mm": self.sigma_mm,
            "fits": [f.to_json() for f in self.fits],
        }


def attribute(
    model: SystemModel,
    x_ref: ArrayLike,
    data: Measurements,
    *,
    sigma_mm: float | ArrayLike,
    reference_mm: ArrayLike | None = None,
    groups: Sequence[StepGroup] | None = None,
    max_iter: int = 10,
) -> Attribution:
    """Fit every candidate group (default `step_groups(model)`) on `data` with the rest held
    at x_ref and choose by BIC (module docstring). sigma_mm: one coordinate's standard
    deviation, scalar or per measurement (n,); reference_mm (n, 3): the residuals before the
    step at the same configurations (None: zero). Raises InsufficientData without data."""
    x0 = np.asarray(x_ref, dtype=float)
    n = len(data)
    if n == 0:
        raise InsufficientData("no measurement after the step to attribute it")
    sigma = np.broadcast_to(np.asarray(sigma_mm, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise InsufficientData("sigma_mm must be finite and > 0")
    ref = np.zeros((n, 3)) if reference_mm is None else np.asarray(reference_mm, dtype=float)
    if ref.shape != (n, 3) or not np.all(np.isfinite(ref)):
        raise InsufficientData(f"reference_mm needs shape ({n}, 3) and finite values")
    cands = tuple(step_groups(model) if groups is None else groups)
    union = tuple(dict.fromkeys(p for g in cands for p in g.params))
    # one evaluation at x_ref for every group's first step (building the chain is the cost)
    p0, J0 = model.point_and_jacobian(x0, data.q_deg, data.c_sensor_mm, union, data.temp_c)
    at_ref = _AtRef(p0, J0.reshape(3 * n, len(union)), {name: j for j, name in enumerate(union)})
    fits = [_fit_group(model, x0, data, ref, sigma, g, max_iter, at_ref) for g in cands]
    fits.sort(key=lambda f: (not f.determined, f.bic))
    return _choose(tuple(fits), n, float(np.median(sigma)))


def _rival(f: GroupFit, best: GroupFit) -> bool:
    """Whether fit f competes with the best one for the margin: another group, and not one
    that holds the best one's parameters and more (J2's encoder zero, theta2 and theta3, over
    J2's zero alone: the same explanation with a parameter to spare, which the BIC's penalty
    alone sets apart); the full set ("several") always competes."""
    if f is best:
        return False
    wider = f.group.name != SEVERAL and set(best.group.params) < set(f.group.params)
    return not wider


def _choose(fits: tuple[GroupFit, ...], n: int, sigma: float) -> Attribution:
    singles = [f for f in fits if f.determined and f.group.name != SEVERAL]
    several = next((f for f in fits if f.group.name == SEVERAL and f.determined), None)
    if not singles:
        return Attribution(fits, SEVERAL, several, np.inf, n, sigma)
    best = singles[0]
    if (several is not None and several.bic < best.bic) or not best.consistent:
        margin = best.bic - several.bic if several is not None else np.inf
        return Attribution(fits, SEVERAL, several, float(margin), n, sigma)
    others = [f.bic for f in fits if f.determined and _rival(f, best)]
    margin = min(others) - best.bic if others else np.inf
    return Attribution(fits, best.group.name, best, float(margin), n, sigma)


@dataclass(frozen=True)
class _AtRef:
    """The points (n, 3) and the Jacobian (3n, L) of every candidate's parameters at x_ref."""

    p: F64
    J: F64
    col: dict[str, int]


def _fit_group(
    model: SystemModel,
    x0: F64,
    data: Measurements,
    ref: F64,
    sigma: F64,
    group: StepGroup,
    max_iter: int,
    at_ref: _AtRef,
) -> GroupFit:
    names = check_active(group.params, model.names)
    k, m = len(names), 3 * len(data)
    cols = np.array([INDEX[p] for p in names])
    w = np.repeat(1.0 / sigma, 3)
    target = data.p_part_mm + ref  # where the points were, relative to the spheres, before
    r0: F64 = (at_ref.p - target).ravel() * w
    if m < k:
        return _undetermined(group, x0, m - k)
    if k == 0:  # nothing moved: the residuals as they are
        chi2_0 = float(np.sum(r0**2))
        empty = np.zeros(0)
        return GroupFit(
            group, x0.copy(), empty, empty, np.zeros((0, 0)), chi2_0, m, chi2_0, True, 0.0
        )

    def full(a: F64) -> F64:
        x = x0.copy()
        x[cols] = a
        return x

    def fun_jac(a: F64) -> tuple[F64, F64]:
        p, J = model.point_and_jacobian(full(a), data.q_deg, data.c_sensor_mm, names, data.temp_c)
        r: F64 = (p - target).ravel() * w
        out: F64 = J.reshape(m, k) * w[:, None]
        return r, out

    J0: F64 = at_ref.J[:, [at_ref.col[p] for p in names]] * w[:, None]
    if np.linalg.matrix_rank(J0 / np.maximum(np.linalg.norm(J0, axis=0), 1e-300)) < k:
        return _undetermined(group, x0, m - k)
    a, r, J = _gauss_newton(fun_jac, x0[cols], r0, J0, max_iter)
    x = full(a)
    cov = np.asarray(np.linalg.pinv(J.T @ J), dtype=np.float64)
    chi2 = float(np.sum(r**2))
    moved = (r - r0).reshape(-1, 3) / w.reshape(-1, 3)  # p(x) - p(x_ref) at the measurements
    return GroupFit(
        group=group,
        x=x,
        step=a - x0[cols],
        std=np.sqrt(np.clip(np.diag(cov), 0.0, None)),
        cov=cov,
        chi2=chi2,
        dof=m - k,
        bic=chi2 + k * float(np.log(m)),
        determined=True,
        shift_mm=float(np.sqrt(np.mean(np.sum(moved**2, axis=1)))),
    )


def _gauss_newton(
    fun_jac: Callable[[F64], tuple[F64, F64]], a: F64, r: F64, J: F64, max_iter: int
) -> tuple[F64, F64, F64]:
    """Gauss-Newton from `a` (a step is small: two or three iterations), each step halved
    while it does not lower the cost; (parameters, residuals, Jacobian) at the end."""
    cost = float(r @ r)
    for _ in range(max_iter):
        delta = np.linalg.lstsq(J, -r, rcond=None)[0]
        for _ in range(8):
            r_new, J_new = fun_jac(a + delta)
            cost_new = float(r_new @ r_new)
            if cost_new <= cost:
                break
            delta = delta / 2.0
        else:
            break
        a, r, J = a + delta, r_new, J_new
        done = cost - cost_new <= 1e-10 * max(cost, 1.0)
        cost = cost_new
        if done:
            break
    return a, r, J


def _undetermined(group: StepGroup, x0: F64, dof: int) -> GroupFit:
    k = len(group.params)
    nan = np.full(k, np.nan)
    return GroupFit(group, x0.copy(), nan, nan, np.full((k, k), np.nan), np.inf, dof, np.inf, False)


def point_shift_mm(
    model: SystemModel,
    x_a: ArrayLike,
    x_b: ArrayLike,
    q_deg: ArrayLike,
    c_sensor_mm: ArrayLike,
    temp_c: ArrayLike | None = None,
) -> float:
    """RMS over K views (K, 6) of how far a point seen at c_sensor_mm (K, 3) moves in the part
    frame between parameters x_a and x_b [mm]: the size of a correction where the sensor
    measures (e.g. at its standoff)."""
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    c = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (len(q), 3))
    t = None if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), (len(q),))
    pa = model.points_part(np.asarray(x_a, float), q, c, temp_c=t)
    pb = model.points_part(np.asarray(x_b, float), q, c, temp_c=t)
    return float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1))))


def predicted_std_mm(
    model: SystemModel,
    fit: GroupFit,
    q_deg: ArrayLike,
    c_sensor_mm: ArrayLike,
    temp_c: ArrayLike | None = None,
) -> float:
    """How well the group's fit predicts the part-frame point at K views: RMS over the views of
    sqrt(trace(H cov H^T) / 3) [mm per coordinate] (inf when undetermined)."""
    if not fit.determined:
        return float("inf")
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    c = np.broadcast_to(np.asarray(c_sensor_mm, dtype=float), (len(q), 3))
    t = None if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), (len(q),))
    H = model.point_jacobian(fit.x, q, c, fit.group.params, temp_c=t)
    var = np.einsum("kil,lm,kim->k", H, fit.cov, H) / 3.0
    return float(np.sqrt(np.mean(var)))
