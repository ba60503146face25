"""Identification of the model parameters from sphere measurements (paper section 3.2).

Residuals: for each measurement i, Delta P_i = T_part_sensor(q_i; x) C_i - P_i^tracker [mm],
stacked x, y, z. Levenberg-Marquardt (`scipy.optimize.least_squares`, method "lm") with the
analytic Jacobian; with a robust loss the trust-region method "trf" (LM does not take one).
Inputs are never mutated; "did not converge" is reported in the result, not raised.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.errors import InsufficientData
from calib.model import BASE_NAMES, INDEX, SystemModel, check_active
from calib.observability import Observability, observability, require_full_rank
from calib.transforms import matrix_to_rotvec

F64 = NDArray[np.float64]
LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")


@dataclass(frozen=True)
class Measurements:
    """Sphere measurements: controller angles `q_deg` (m, 6), centres in the sensor frame
    `c_sensor_mm` (m, 3), the tracker's centres in the part frame `p_part_mm` (m, 3) and the
    sphere ids `targets` (m,); optionally the cell temperature `temp_c` (m,) [degC] at each
    measurement (the compliant model's thermal term uses it)."""

    q_deg: F64
    c_sensor_mm: F64
    p_part_mm: F64
    targets: tuple[str, ...]
    temp_c: F64 | None = None

    def __post_init__(self) -> None:
        m = len(self.targets)
        shapes = {"q_deg": (m, 6), "c_sensor_mm": (m, 3), "p_part_mm": (m, 3), "temp_c": (m,)}
        for name, shape in shapes.items():
            if getattr(self, name) is None:
                continue
            arr = np.asarray(getattr(self, name))
            if arr.shape != shape:
                raise InsufficientData(f"{name} has shape {arr.shape}, expected {shape}")
            if not np.all(np.isfinite(arr)):
                raise InsufficientData(f"{name} holds a NaN or infinite value")

    def __len__(self) -> int:
        return len(self.targets)

    def subset(self, rows: ArrayLike) -> Measurements:
        r = np.asarray(rows)
        return Measurements(
            self.q_deg[r],
            self.c_sensor_mm[r],
            self.p_part_mm[r],
            tuple(self.targets[i] for i in np.arange(len(self))[r]),
            None if self.temp_c is None else self.temp_c[r],
        )


def residuals(model: SystemModel, x: F64, data: Measurements) -> F64:
    """Position errors (m, 3) [mm] of the model at parameters x (full vector)."""
    p = model.points_part(x, data.q_deg, data.c_sensor_mm, temp_c=data.temp_c)
    out: F64 = p - data.p_part_mm
    return out


def stacked_jacobian(model: SystemModel, x: F64, data: Measurements, active: Sequence[str]) -> F64:
    """The identification Jacobian (3m, L): d(stacked residuals) / d(active parameters)."""
    J = model.point_jacobian(x, data.q_deg, data.c_sensor_mm, active, temp_c=data.temp_c)
    out: F64 = J.reshape(-1, len(active))
    return out


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of `identify`. `x` is the full parameter vector (37,), `active` the identified
    names, `std` their standard uncertainties (residual variance times (J^T J)^-1), `corr`
    their correlation matrix, `residuals_mm` (m, 3) at the solution."""

    x: F64
    x_start: F64
    active: tuple[str, ...]
    std: F64
    corr: F64
    residuals_mm: F64
    rms_mm: float
    max_mm: float
    sigma_mm: float
    observability: Observability
    success: bool
    status: int
    message: str
    nfev: int
    #: the mean cell temperature of the measurements [degC] (None without temperatures): the
    #: temperature whose arm lengths a rigid identification's lengths are
    temp_c: float | None = None

    def value(self, name: str) -> float:
        return float(self.x[INDEX[name]])


def identify(
    model: SystemModel,
    data: Measurements,
    *,
    active: Sequence[str] | None = None,
    x0: F64 | None = None,
    loss: str = "linear",
    f_scale_mm: float = 0.05,
    max_nfev: int = 200,
    jac: str = "analytic",
    align: bool = True,
) -> IdentificationResult:
    """Identify the `active` parameters (default: the model's, the paper's 30 for the rigid
    model) from `data`, starting at x0 (default: nominal).

    Raises InsufficientData for fewer equations than parameters and NotIdentifiable (naming
    the parameters of each null-space direction) for a rank-deficient problem at the start.
    `jac="2-point"` or `"3-point"` uses finite differences instead (the benchmark's reference).
    With `align` (default) and the part->base pose identified, the start is first moved to the
    closed-form alignment of the measured centres onto the tracker's (`align_part_base`), so
    that a part->base guess off by any rotation still converges.
    """
    names = check_active(
        model.default_active(data.temp_c) if active is None else active, model.names
    )
    if loss not in LOSSES:
        raise ValueError(f"unknown loss '{loss}' (choose from {', '.join(LOSSES)})")
    if 3 * len(data) < len(names):
        raise InsufficientData(
            f"{len(data)} measurements give {3 * len(data)} equations for {len(names)} "
            f"parameters: at least {-(-len(names) // 3)} measurements are needed"
        )
    x_start = model.nominal_x() if x0 is None else np.array(x0, dtype=float)
    if align and set(BASE_NAMES) <= set(names):
        x_start = align_part_base(model, x_start, data)
    cols = np.array([INDEX[n] for n in names])
    require_full_rank(stacked_jacobian(model, x_start, data, names), names)

    def full(xa: F64) -> F64:
        x = x_start.copy()
        x[cols] = xa
        return x

    def fun(xa: F64) -> F64:
        return residuals(model, full(xa), data).ravel()

    def jacobian(xa: F64) -> F64:
        return stacked_jacobian(model, full(xa), data, names)

    from scipy.optimize import least_squares  # here: about half a second to import

    method = "lm" if loss == "linear" else "trf"
    sol = least_squares(
        fun,
        x_start[cols],
        jac=jacobian if jac == "analytic" else jac,
        method=method,
        loss=loss,
        f_scale=f_scale_mm,
        x_scale="jac",
        max_nfev=max_nfev,
    )
    x = full(sol.x)
    return _result(model, data, names, x, x_start, sol)


def _result(
    model: SystemModel,
    data: Measurements,
    names: tuple[str, ...],
    x: F64,
    x_start: F64,
    sol: object,
    given: F64 | None = None,
) -> IdentificationResult:
    res = residuals(model, x, data)
    J = stacked_jacobian(model, x, data, names)
    dof = max(res.size - len(names), 1)
    s2 = float(np.sum(res**2)) / dof
    cov = given
    if cov is None:
        _, sv, Vt = np.linalg.svd(J, full_matrices=False)
        inv_sv2 = np.where(sv > 1e-12 * sv[0], 1.0 / sv**2, 0.0)
        cov = (Vt.T * inv_sv2) @ Vt * s2
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    denom = np.outer(std, std)
    corr = np.divide(cov, denom, out=np.zeros_like(cov), where=denom > 0)
    # an estimate made elsewhere holds its prior: `data` alone need not determine it
    obs = require_full_rank(J, names) if given is None else observability(J, max(len(res), 1))
    e = np.linalg.norm(res, axis=1)
    return IdentificationResult(
        x=x,
        x_start=x_start,
        active=names,
        std=std,
        corr=corr,
        residuals_mm=res,
        rms_mm=float(np.sqrt(np.mean(e**2))),
        max_mm=float(e.max()),
        sigma_mm=float(np.sqrt(s2)),
        observability=obs,
        success=bool(getattr(sol, "success", False)),
        status=int(getattr(sol, "status", 0)),
        message=str(getattr(sol, "message", "")),
        nfev=int(getattr(sol, "nfev", 0)),
        temp_c=None if data.temp_c is None else float(np.mean(data.temp_c)),
    )


@dataclass(frozen=True)
class _Given:
    """What `_result` reads of a solver's outcome, for an estimate made elsewhere."""

    success: bool = True
    status: int = 1
    message: str = "the estimator's posterior"
    nfev: int = 0


def posterior_result(
    model: SystemModel,
    data: Measurements,
    x: F64,
    active: Sequence[str],
    cov: F64,
    x_start: F64,
) -> IdentificationResult:
    """An estimate made elsewhere as an identification's outcome on `data`: the in-line
    estimator's posterior (calib.cellstate: x, the full vector, and `cov` of its `active`
    parameters, which holds what came before `data` as well as `data`), with its residuals on
    `data`, their RMS and the observability `data` alone gives (the gates read them)."""
    names = tuple(active)
    cov = np.asarray(cov, float)
    if cov.shape != (len(names), len(names)):
        raise ValueError(f"cov must be {len(names)}x{len(names)}, got {cov.shape}")
    return _result(model, data, names, np.asarray(x, float), x_start, _Given(), 0.5 * (cov + cov.T))


def held_sensitivity(
    model: SystemModel, data: Measurements, x: F64, fitted: Sequence[str], held: Sequence[str]
) -> F64:
    """G = d(fitted) / d(held) (len(fitted), len(held)) of the least-squares fit of `fitted` on
    `data` with `held` fixed, at its solution x: moving the held values by da moves the fit's
    solution by G da, G = -(J_b^T J_b)^-1 J_b^T J_a, J_b and J_a the stacked residuals'
    Jacobians in the fitted and the held parameters (equal weights, as `identify`'s; the
    pseudo-inverse cut as its covariance's)."""
    Jb = stacked_jacobian(model, x, data, fitted)
    Ja = stacked_jacobian(model, x, data, held)
    out: F64 = -np.linalg.pinv(Jb, rcond=1e-12) @ Ja
    return out


def with_held(cov_held: F64, cov_fit: F64, gain: F64) -> F64:
    """The joint covariance of [held; fitted] for a fit conditional on held values that are
    themselves estimates (covariance `cov_held`): `cov_fit` the fit's own (as if the held
    values were exact), `gain` its `held_sensitivity`. The fitted block is cov_fit + G C_aa
    G^T, the cross block G C_aa (b = f(data, a), linearised: the fit's noise independent of
    the held values' errors)."""
    k = cov_held.shape[0]
    ga = gain @ cov_held
    out = np.zeros((k + cov_fit.shape[0],) * 2)
    out[:k, :k] = cov_held
    out[k:, k:] = cov_fit + ga @ gain.T
    out[k:, :k] = ga
    out[:k, k:] = ga.T
    return out


def kabsch(a: F64, b: F64) -> tuple[F64, F64] | None:
    """(R, t) minimising sum |R a_i + t - b_i|^2 (Kabsch/Horn, proper rotation), for point sets
    (n, 3); None when b spans less than a plane (fewer than 3 distinct, non-collinear points)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    sv_b = np.linalg.svd(b - cb, compute_uv=False)
    if sv_b.size < 2 or sv_b[1] < 1e-6 * max(sv_b[0], 1.0) or sv_b[1] < 1e-3:
        return None
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R: F64 = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cb - R @ ca


def align_part_base(model: SystemModel, x: F64, data: Measurements) -> F64:
    """x with its part->base pose replaced by the rigid transform that best maps the measured
    centres, carried to the base frame with the rest of x, onto the tracker's centres. The
    joints and the hand-eye stay as they are; x is returned unchanged when the targets do not
    span a plane."""
    T_pb = model.T_part_base(x)
    p_base = (model.points_part(x, data.q_deg, data.c_sensor_mm) - T_pb[:3, 3]) @ T_pb[:3, :3]
    fit = kabsch(p_base, data.p_part_mm)
    if fit is None:
        return x
    R, t = fit
    out = x.copy()
    out[0:3] = t
    out[3:6] = matrix_to_rotvec(model.T_part_base_nominal[:3, :3].T @ R)
    return out
