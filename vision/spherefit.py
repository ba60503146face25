"""Sphere fit to a point cloud: Pratt's algebraic fit as the start, then geometric least squares
with a robust loss (soft-L1, then Cauchy), with a free radius and with the certified radius.

The geometric step is a small iteratively reweighted Gauss-Newton (4 or 3 unknowns, tens of
thousands of points): it converges in a handful of iterations and costs a few milliseconds,
where scipy.optimize.least_squares would spend most of its time in per-call overhead.

Quality: number of points and inliers, RMS residual of the inliers, the cap's angular coverage,
the free radius and its deviation from the certified radius. `fit_sphere` raises
SphereFitRejected (carrying the quality) when a threshold fails: a bad fit never returns a centre.

Two facts, two fits: the centre is the robust fit's (a ghost-stripe point must not move it);
the probing error form PF (`form_error`) is VDI/VDE 2634-2's, the range of the radial distances
of all the points from the plain least-squares sphere with free radius, of which the guideline
lets at most 0.3 % of the points be left out as outliers (`FORM_MAX_OUTLIER_SHARE`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from vision.errors import SphereFitRejected, TooFewPoints

F64 = NDArray[np.float64]

#: the largest share of a sweep's points VDI/VDE 2634-2 lets PF leave out as outliers
FORM_MAX_OUTLIER_SHARE = 0.003


@dataclass(frozen=True)
class FitThresholds:
    """Limits that turn a fit into a rejection (mm, degrees)."""

    min_points: int = 300
    min_inlier_fraction: float = 0.8
    max_rms_mm: float = 0.06
    min_coverage_deg: float = 25.0
    max_radius_dev_mm: float = 0.05
    max_centre_shift_mm: float = 0.05


@dataclass(frozen=True)
class FitQuality:
    """n_points, n_inliers; rms_mm of inlier residuals; coverage_deg: 95th percentile of the
    angle between the point normals and the cap's mean normal; radius_free_mm; radius_dev_mm =
    free - certified (0 without a certified radius); centre_shift_mm between free and certified
    fits; iterations of the geometric fit; form_mm: VDI/VDE 2634-2's probing error form PF,
    the range (max - min) of the radial distances from the least-squares sphere with free
    radius (`form_error`); form_outliers: the points PF left out (at most 0.3 %)."""

    n_points: int
    n_inliers: int
    rms_mm: float
    coverage_deg: float
    radius_free_mm: float
    radius_dev_mm: float
    centre_shift_mm: float
    iterations: int
    form_mm: float = 0.0
    form_outliers: int = 0


@dataclass(frozen=True, eq=False)
class SphereFit:
    """centre_mm shape=(3,), radius_mm (certified if given, else free), cov_mm2 shape=(3, 3) of
    the centre (inflated for residual correlation along the stripe), quality, status "ok"."""

    centre_mm: F64
    radius_mm: float
    cov_mm2: F64
    quality: FitQuality
    status: str = "ok"


def fit_sphere_pratt(X: F64) -> tuple[F64, float]:
    """Pratt's algebraic sphere fit (unbiased on small caps, unlike Kasa).

    X: shape=(n, 3) [mm], n >= 4. Returns the centre shape=(3,) and the radius [mm].
    """
    m = X.mean(axis=0)
    Yt = (X - m).T  # (3, n): the sums below run along contiguous rows
    scale = float(np.sqrt(np.einsum("ij,ij->", Yt, Yt) / len(X))) or 1.0
    Zt = np.empty((5, len(X)))
    np.divide(Yt, scale, out=Zt[1:4])
    np.einsum("ij,ij->j", Zt[1:4], Zt[1:4], out=Zt[0])
    Zt[4] = 1.0
    M = Zt @ Zt.T / len(X)
    B = np.diag([0.0, 1.0, 1.0, 1.0, 0.0])
    B[0, 4] = B[4, 0] = -2.0
    evals, evecs = scipy.linalg.eig(M, B)
    evals = np.real(evals)
    cand = np.flatnonzero(np.isfinite(evals) & (evals > -1e-12))
    if cand.size == 0:
        raise SphereFitRejected("algebraic fit found no sphere")
    a = np.real(evecs[:, cand[np.argmin(evals[cand])]])
    if abs(a[0]) < 1e-14:
        raise SphereFitRejected("points lie on a plane, not a sphere")
    centre = -a[1:4] / (2 * a[0])
    r2 = (a[1:4] @ a[1:4] - 4 * a[0] * a[4]) / (4 * a[0] ** 2)
    return centre * scale + m, float(np.sqrt(max(r2, 0.0)) * scale)


def _median(a: F64) -> float:
    """np.median of a 1-D array (the same value) from one partial sort, without np.median's
    generic-axis overhead: this runs a few times per fit on every point."""
    n = a.shape[0]
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, [k - 1, k])
    return float((part[k - 1] + part[k]) / 2)


def _robust_scale(r: F64) -> float:
    return max(1.4826 * _median(np.abs(r - _median(r))), 1e-4)


def _weights(r: F64, scale: float, *, cauchy: bool) -> F64:
    """IRLS weights: soft-L1 while far from the solution, then Cauchy (redescending, so that
    gross outliers such as ghost-stripe points lose all influence; 95 % efficient on Gaussian
    residuals at c = 2.385 sigma)."""
    if cauchy:
        return np.asarray(1.0 / (1.0 + (r / (2.385 * scale)) ** 2))
    return np.asarray(1.0 / np.sqrt(1.0 + (r / (2.0 * scale)) ** 2))


def fit_sphere_geometric(
    X: F64,
    centre0: F64,
    radius_mm: float,
    *,
    fixed_radius: bool,
    robust: bool = True,
    max_iter: int = 30,
    tol_mm: float = 1e-7,
) -> tuple[F64, float, F64, F64, int]:
    """Robust geometric fit minimising sum rho(|X - c| - R) by IRLS (see `_weights`), until
    a step moves the centre and radius by less than `tol_mm` (0.1 nm: far below any sensor's
    resolution); `robust=False`: plain least squares (every point weighs 1, Gauss-Newton).

    Returns centre, radius, final residuals shape=(n,), the weighted normal matrix inverse
    (centre block first) times the residual variance, and the number of iterations.
    """
    c, R = centre0.astype(np.float64).copy(), float(radius_mm)
    scale = 0.0
    n_col = 3 if fixed_radius else 4
    Xt = np.ascontiguousarray(X.T)  # (3, n): every pass below runs along contiguous rows
    D = np.empty_like(Xt)
    # the Jacobian of r = |X - c| - R is -A.T: rows of A the unit vectors (X - c) / |X - c|
    # and, with a free radius, ones; the Gauss-Newton step solves (A W A.T) s = A W r
    A = np.ones((n_col, Xt.shape[1]))
    for it in range(1, max_iter + 1):
        np.subtract(Xt, c[:, None], out=D)
        d = np.sqrt(np.einsum("ij,ij->j", D, D))
        r = d - R
        if robust and (it == 1 or it % 3 == 0):
            scale = _robust_scale(r)
        np.divide(D, d, out=A[:3])
        Aw = A * _weights(r, scale, cauchy=it > 4) if robust else A
        step = np.linalg.solve(Aw @ A.T, Aw @ r)
        c += step[:3]
        if not fixed_radius:
            R += float(step[3])
        if float(np.max(np.abs(step))) < tol_mm:
            break
    np.subtract(Xt, c[:, None], out=D)
    r = np.sqrt(np.einsum("ij,ij->j", D, D)) - R
    w = _weights(r, scale, cauchy=True) if robust else np.ones_like(r)
    sigma2 = float((w * r * r).sum() / max(w.sum() - n_col, 1.0))
    cov = np.asarray(np.linalg.inv((A * w) @ A.T) * sigma2, dtype=np.float64)
    return c, R, r, cov, it


def _coverage_deg(X: F64, c: F64) -> float:
    u = X - c
    u /= np.sqrt(np.einsum("ij,ij->i", u, u))[:, None]
    mean = u.mean(axis=0)
    mean /= np.linalg.norm(mean)
    return float(np.degrees(np.percentile(np.arccos(np.clip(u @ mean, -1.0, 1.0)), 95)))


def _correlation_inflation(r: F64) -> float:
    """Variance inflation for residuals correlated along the acquisition order (speckle)."""
    if len(r) < 10:
        return 1.0
    rc = r - r.mean()
    rho = float((rc[1:] @ rc[:-1]) / max(rc @ rc, 1e-300))
    rho = min(max(rho, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


def fit_sphere(
    X: F64, certified_radius_mm: float | None = None, thresholds: FitThresholds | None = None
) -> SphereFit:
    """Fit a sphere to points X shape=(n, 3) [mm] (ordered as acquired) and check its quality.

    With a certified radius the reported centre is the fixed-radius fit and the free fit is the
    health check; otherwise the free fit is reported. Raises TooFewPoints or SphereFitRejected.
    """
    th = thresholds or FitThresholds()
    if len(X) < th.min_points:
        raise TooFewPoints(len(X), th.min_points)
    c0, r0 = fit_sphere_pratt(X)
    c_free, r_free, res, cov, iters = fit_sphere_geometric(X, c0, r0, fixed_radius=False)
    form_mm, form_outliers = form_error(X, c_free, r_free)
    c, radius, cov_c = c_free, r_free, cov[:3, :3]
    shift, dev = 0.0, 0.0
    if certified_radius_mm is not None:
        c, radius, res, cov_c, it2 = fit_sphere_geometric(
            X, c_free, certified_radius_mm, fixed_radius=True
        )
        iters += it2
        shift = float(np.linalg.norm(c - c_free))
        dev = r_free - certified_radius_mm
    scale = _robust_scale(res)
    inl = np.abs(res) < 4.0 * scale
    quality = FitQuality(
        n_points=len(X),
        n_inliers=int(inl.sum()),
        rms_mm=float(np.sqrt(np.mean(res[inl] ** 2))) if inl.any() else float("inf"),
        coverage_deg=_coverage_deg(X[inl], c) if inl.any() else 0.0,
        radius_free_mm=r_free,
        radius_dev_mm=dev,
        centre_shift_mm=shift,
        iterations=iters,
        form_mm=form_mm,
        form_outliers=form_outliers,
    )
    _check(quality, th)
    cov_c = cov_c * _correlation_inflation(res)
    return SphereFit(centre_mm=c, radius_mm=radius, cov_mm2=cov_c, quality=quality)


def form_error(
    X: F64,
    centre0_mm: F64,
    radius0_mm: float,
    max_outlier_share: float = FORM_MAX_OUTLIER_SHARE,
    passes: int = 3,
) -> tuple[float, int]:
    """VDI/VDE 2634-2's probing error form PF [mm] of the points X shape=(n, 3) [mm]: the range
    of their radial distances from the least-squares sphere with free radius. At most
    floor(max_outlier_share n) points, those farthest from the sphere, are left out as outliers
    and the sphere fitted again without them, until the points left out stay the same (at most
    `passes` fits). centre0_mm, radius0_mm: where the fit starts (the robust fit's).
    Returns PF and the number of points left out."""
    n = len(X)
    k = int(np.floor(max_outlier_share * n))
    keep = np.ones(n, dtype=bool)
    c, R = np.asarray(centre0_mm, dtype=np.float64), float(radius0_mm)
    for _ in range(passes):
        c, R, _, _, _ = fit_sphere_geometric(X[keep], c, R, fixed_radius=False, robust=False)
        r = np.sqrt(np.einsum("ij,ij->i", X - c, X - c)) - R
        if k == 0:
            break
        nearest = np.ones(n, dtype=bool)
        nearest[np.argpartition(np.abs(r), n - k)[n - k :]] = False
        if np.array_equal(nearest, keep):
            break
        keep = nearest
    else:  # the last pass chose other points: the sphere of those
        c, R, _, _, _ = fit_sphere_geometric(X[keep], c, R, fixed_radius=False, robust=False)
        r = np.sqrt(np.einsum("ij,ij->i", X - c, X - c)) - R
    kept = r[keep]
    return float(kept.max() - kept.min()), n - int(keep.sum())


def _check(q: FitQuality, th: FitThresholds) -> None:
    """Raise SphereFitRejected naming the first failed threshold."""
    checks = [
        (q.n_inliers >= th.min_points, f"{q.n_inliers} inliers < {th.min_points}"),
        (
            q.n_inliers >= th.min_inlier_fraction * q.n_points,
            f"inlier fraction {q.n_inliers / max(q.n_points, 1):.2f} < {th.min_inlier_fraction}",
        ),
        (q.rms_mm <= th.max_rms_mm, f"RMS residual {q.rms_mm:.4f} mm > {th.max_rms_mm}"),
        (
            q.coverage_deg >= th.min_coverage_deg,
            f"cap coverage {q.coverage_deg:.1f} deg < {th.min_coverage_deg}",
        ),
        (
            abs(q.radius_dev_mm) <= th.max_radius_dev_mm,
            f"free radius deviates {q.radius_dev_mm:+.4f} mm from the certified radius",
        ),
        (
            q.centre_shift_mm <= th.max_centre_shift_mm,
            f"free and certified-radius centres differ by {q.centre_shift_mm:.4f} mm",
        ),
    ]
    for ok, reason in checks:
        if not ok:
            raise SphereFitRejected(reason, q)
