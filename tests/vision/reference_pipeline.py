"""The sweep -> centre pipeline's hot spots as they were before they were made faster (kept
verbatim as the oracle the faster code must match): the full-frame windowed-centroid stripe
extraction (now `vision.stripe.extract_fast` reads only the stripe's columns and rows, the
per-row arithmetic of a sweep at once) and the geometric sphere fit on (n, 3) points (now on
(3, n) rows with one normal-matrix product)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from vision.stripe import StripePoints, StripeSettings

F64 = NDArray[np.float64]


def _robust_scale(r: F64) -> float:
    """The residuals' MAD scale (the oracle's own, with np.median: not the code it checks)."""
    return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), 1e-4)


def _weights(r: F64, scale: float, *, cauchy: bool) -> F64:
    """IRLS weights: soft-L1 far from the solution, then Cauchy at c = 2.385 sigma."""
    if cauchy:
        return np.asarray(1.0 / (1.0 + (r / (2.385 * scale)) ** 2))
    return np.asarray(1.0 / np.sqrt(1.0 + (r / (2.0 * scale)) ** 2))


def _median_of_codes(codes: NDArray[np.integer]) -> float:
    """np.median of non-negative integers, from their histogram (no sort)."""
    cum = np.cumsum(np.bincount(codes.ravel()))
    n = codes.size
    lo = np.searchsorted(cum, (n - 1) // 2, side="right")
    hi = np.searchsorted(cum, n // 2, side="right")
    return 0.5 * float(lo + hi)


def _background(frame: NDArray[np.generic]) -> tuple[float, float]:
    """Background level and noise sigma [DN] from a sparse sample (the stripe is thin)."""
    sample = frame[::7, ::9]
    if sample.dtype.kind != "u":
        sample_f = sample.astype(np.float32).ravel()
        med = float(np.median(sample_f))
        mad = float(np.median(np.abs(sample_f - med)))
        return med, max(1.4826 * mad, 0.5)
    codes = sample.astype(np.int64)
    med = _median_of_codes(codes)
    mad = 0.5 * _median_of_codes(np.abs(2 * codes - int(2 * med)))  # exact for half codes
    return med, max(1.4826 * mad, 0.5)


def _top_code(frame: NDArray[np.generic], settings: StripeSettings) -> int:
    if settings.saturation_dn is not None:
        return settings.saturation_dn
    return 255 if frame.dtype == np.uint8 else 4095


def extract_fast_reference(
    frame: NDArray[np.generic], settings: StripeSettings | None = None
) -> StripePoints:
    """Windowed grey centroid per row, background-subtracted; see the module docstring."""
    s = settings or StripeSettings()
    h, w = frame.shape
    bg, sigma = _background(frame)
    col = np.argmax(frame, axis=1)
    rows = np.arange(h)
    peak = frame[rows, col].astype(np.float32) - bg
    ok = peak > max(s.min_peak_dn, s.noise_k * sigma)
    rows, col, peak = rows[ok], col[ok], peak[ok]
    if rows.size == 0:
        z = np.zeros(0)
        return StripePoints(z, z, z, z)
    k = s.half_window_px
    offs = np.arange(-k, k + 1)
    idx = np.clip(col[:, None] + offs, 0, w - 1)
    win = frame[rows[:, None], idx].astype(np.float32)
    saturated = (win >= _top_code(frame, s)).any(axis=1)
    half = (bg + 0.5 * peak).astype(frame.dtype)
    above_row = np.count_nonzero(frame[rows] > half[:, None], axis=1)
    above_win = np.count_nonzero(win > half[:, None], axis=1)
    multi = above_row > above_win
    wts = np.clip(win - bg - 3.0 * sigma, 0.0, None)
    wsum = wts.sum(axis=1)
    centre = (wts * offs).sum(axis=1) / np.maximum(wsum, 1e-9)
    width = np.sqrt((wts * (offs - centre[:, None]) ** 2).sum(axis=1) / np.maximum(wsum, 1e-9))
    edge_bright = np.maximum(win[:, 0], win[:, -1]) - bg > 0.5 * peak
    wide = (width > s.max_width_px) | edge_bright
    good = ~(saturated | multi | wide) & (wsum > 0)
    return StripePoints(
        u_px=(col[good] + centre[good]).astype(np.float64),
        v_px=rows[good].astype(np.float64),
        peak_dn=peak[good].astype(np.float64),
        width_px=width[good].astype(np.float64),
        n_saturated=int(saturated.sum()),
        n_multi_peak=int((multi & ~saturated).sum()),
        n_too_wide=int((wide & ~multi & ~saturated).sum()),
    )


def fit_sphere_geometric_reference(
    X: F64,
    centre0: F64,
    radius_mm: float,
    *,
    fixed_radius: bool,
    max_iter: int = 30,
    tol_mm: float = 1e-7,
) -> tuple[F64, float, F64, F64, int]:
    """Robust geometric fit minimising sum rho(|X - c| - R) by IRLS (see `_weights`), until
    a step moves the centre and radius by less than `tol_mm` (0.1 nm: far below any sensor's
    resolution).

    Returns centre, radius, final residuals shape=(n,), the weighted normal matrix inverse
    (centre block first) times the residual variance, and the number of iterations.
    """
    c, R = centre0.astype(np.float64).copy(), float(radius_mm)
    scale = 0.0
    n_col = 3 if fixed_radius else 4
    J = np.empty((len(X), n_col))
    if not fixed_radius:
        J[:, 3] = -1.0
    for it in range(1, max_iter + 1):
        D = X - c
        d = np.sqrt(np.einsum("ij,ij->i", D, D))
        r = d - R
        if it == 1 or it % 3 == 0:
            scale = _robust_scale(r)
        w = _weights(r, scale, cauchy=it > 4)
        np.divide(D, -d[:, None], out=J[:, :3])
        JW = J * w[:, None]
        step = np.linalg.solve(JW.T @ J, -(JW.T @ r))
        c += step[:3]
        if not fixed_radius:
            R += float(step[3])
        if float(np.max(np.abs(step))) < tol_mm:
            break
    D = X - c
    r = np.sqrt(np.einsum("ij,ij->i", D, D)) - R
    w = _weights(r, scale, cauchy=True)
    sigma2 = float((w * r * r).sum() / max(w.sum() - n_col, 1.0))
    cov = np.asarray(np.linalg.inv((J * w[:, None]).T @ J) * sigma2, dtype=np.float64)
    return c, R, r, cov, it
