"""Sub-pixel laser-stripe extraction, vectorised over a frame.

The stripe runs along the image rows (the galvo sweeps it across the columns), so there is at
most one stripe point per row. Two modes:

- "fast": per row the brightest pixel, then the grey centroid of a window around it after
  subtracting the frame's background and a noise threshold (one pass over the frame for the
  argmax, one for the multi-peak count);
- "precise": Steger's method (1998) inside the bounding band of the fast result: Gaussian
  derivatives, the Hessian's dominant eigenvector as the line normal, and the sub-pixel extremum
  along it.

Per row a profile is rejected when saturated (any pixel at the top code in the window), multi-peak
(a pixel outside the window brighter than half the peak) or too wide (RMS width above a limit), or
too weak. Frames are uint8 or uint16 arrays shape=(H, W); points are in pixels (u column, v row).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class StripeSettings:
    """Thresholds of the extraction. half_window_px: centroid window +-; min_peak_dn: peak above
    background needed (also >= noise_k * noise); max_width_px: RMS width limit; saturation_dn:
    top code (None: from the dtype, 255 for uint8, 4095 for uint16 = 12 bit); steger_sigma_px:
    Gaussian scale of the precise mode (about the stripe's sigma)."""

    half_window_px: int = 6
    min_peak_dn: float = 12.0
    noise_k: float = 6.0
    max_width_px: float = 3.5
    saturation_dn: int | None = None
    steger_sigma_px: float = 1.8
    band_px: int = 8


@dataclass(frozen=True, eq=False)
class StripePoints:
    """Valid stripe points of one frame: u_px, v_px, peak_dn (above background), width_px (RMS),
    all shape=(n,); and how many rows each rejection reason removed."""

    u_px: F64
    v_px: F64
    peak_dn: F64
    width_px: F64
    n_saturated: int = 0
    n_multi_peak: int = 0
    n_too_wide: int = 0

    def __len__(self) -> int:
        return int(self.u_px.shape[0])


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


def _empty() -> StripePoints:
    z = np.zeros(0)
    return StripePoints(z, z, z, z)


def extract_fast(
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
        return _empty()
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


def _derivative_kernels(sigma: float) -> tuple[F64, F64, F64]:
    r = int(np.ceil(3.5 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    # correlation kernels (OpenCV does not flip): exact on ramps and parabolas after truncation
    g1 = x / sigma**2 * g
    g1 /= g1 @ x
    g2 = (x**2 / sigma**4 - 1.0 / sigma**2) * g
    g2 -= g2.mean()
    g2 /= 0.5 * (g2 @ x**2)
    return g, g1, g2


def extract_precise(
    frame: NDArray[np.generic],
    settings: StripeSettings | None = None,
    coarse: StripePoints | None = None,
) -> StripePoints:
    """Steger's Hessian method in the band around the fast result (same rows, same rejections).

    Returns points whose (u, v) is the sub-pixel line centre along the local normal.
    """
    s = settings or StripeSettings()
    fast = coarse if coarse is not None else extract_fast(frame, s)
    if len(fast) == 0:
        return fast
    h, w = frame.shape
    r0 = max(int(fast.v_px.min()) - s.band_px, 0)
    r1 = min(int(fast.v_px.max()) + s.band_px + 1, h)
    c0 = max(int(fast.u_px.min()) - s.band_px, 0)
    c1 = min(int(np.ceil(fast.u_px.max())) + s.band_px + 1, w)
    crop = frame[r0:r1, c0:c1].astype(np.float32)
    g, g1, g2 = _derivative_kernels(s.steger_sigma_px)
    rx = cv2.sepFilter2D(crop, cv2.CV_32F, g1, g, borderType=cv2.BORDER_REPLICATE)
    ry = cv2.sepFilter2D(crop, cv2.CV_32F, g, g1, borderType=cv2.BORDER_REPLICATE)
    rxx = cv2.sepFilter2D(crop, cv2.CV_32F, g2, g, borderType=cv2.BORDER_REPLICATE)
    ryy = cv2.sepFilter2D(crop, cv2.CV_32F, g, g2, borderType=cv2.BORDER_REPLICATE)
    rxy = cv2.sepFilter2D(crop, cv2.CV_32F, g1, g1, borderType=cv2.BORDER_REPLICATE)
    vv = fast.v_px.astype(np.intp) - r0
    base = np.rint(fast.u_px).astype(np.intp) - c0
    best_u = np.full(len(fast), np.nan)
    best_v = np.full(len(fast), np.nan)
    best_off = np.full(len(fast), np.inf)
    for d in (0, -1, 1):
        uu = np.clip(base + d, 0, c1 - c0 - 1)
        a, b, c = rxx[vv, uu], rxy[vv, uu], ryy[vv, uu]
        # eigenvector of the most negative eigenvalue of [[a, b], [b, c]] (bright line)
        lam = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b * b)
        nx, ny = b, lam - a
        degenerate = np.abs(nx) + np.abs(ny) < 1e-12
        nx = np.where(degenerate, 1.0, nx)
        ny = np.where(degenerate, 0.0, ny)
        norm = np.hypot(nx, ny)
        nx, ny = nx / norm, ny / norm
        denom = a * nx * nx + 2 * b * nx * ny + c * ny * ny
        t = -(rx[vv, uu] * nx + ry[vv, uu] * ny) / np.where(denom < 0, denom, -np.inf)
        px, py = t * nx, t * ny
        off = np.maximum(np.abs(px), np.abs(py))
        better = (off < best_off) & (denom < 0)
        best_off = np.where(better, off, best_off)
        best_u = np.where(better, uu + px + c0, best_u)
        best_v = np.where(better, vv + py + r0, best_v)
    good = best_off <= 0.6
    return StripePoints(
        u_px=best_u[good],
        v_px=best_v[good],
        peak_dn=fast.peak_dn[good],
        width_px=fast.width_px[good],
        n_saturated=fast.n_saturated,
        n_multi_peak=fast.n_multi_peak,
        n_too_wide=fast.n_too_wide,
    )


def extract_stripe(
    frame: NDArray[np.generic], mode: str = "fast", settings: StripeSettings | None = None
) -> StripePoints:
    """Stripe points of one frame shape=(H, W); mode "fast" or "precise"."""
    if frame.ndim != 2:
        raise ValueError(f"frame must be 2-D, got shape {frame.shape}")
    if mode == "fast":
        return extract_fast(frame, settings)
    if mode == "precise":
        return extract_precise(frame, settings)
    raise ValueError(f"unknown stripe mode {mode!r} (fast, precise)")
