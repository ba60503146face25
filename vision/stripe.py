"""Sub-pixel laser-stripe extraction, vectorised over a frame and over a sweep.

The stripe runs along the image rows (the galvo sweeps it across the columns), so there is at
most one stripe point per row. Two modes:

- "fast": per row the brightest pixel, then the grey centroid of a window around it after
  subtracting the frame's background and a noise threshold. One pass over the whole frame
  (column maxima) finds the band of columns that can hold a peak; the rest reads that band only,
  and `extract_sweep` does the per-row arithmetic of all frames of a sweep at once;
- "precise": Steger's method (1998) inside the bounding band of the fast result: Gaussian
  derivatives, the Hessian's dominant eigenvector as the line normal, and the sub-pixel extremum
  along it.

Per row a profile is rejected when saturated (any pixel at the top code in the window), multi-peak
(a pixel outside the window brighter than half the peak) or too wide (RMS width above a limit), or
too weak. Frames are uint8 or uint16 arrays shape=(H, W); points are in pixels (u column, v row).
"""

from __future__ import annotations

from collections.abc import Sequence
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
    all shape=(n,); and how many rows each rejection reason removed; flux_dn (n,): the row's
    light in the centroid window, summed above background (None: not measured). Where an edge
    cuts the stripe across its width the row's flux falls while its peak stays (the peak pixel
    is still on the face): its share of an uncut row's is the share of the stripe the face
    lights (vision.sheet)."""

    u_px: F64
    v_px: F64
    peak_dn: F64
    width_px: F64
    n_saturated: int = 0
    n_multi_peak: int = 0
    n_too_wide: int = 0
    flux_dn: F64 | None = None

    def __len__(self) -> int:
        return int(self.u_px.shape[0])


def _histogram_median(hist: NDArray[np.generic]) -> float:
    """The median (np.median's, halves included) of values given by their histogram
    hist[v] = how many values equal v."""
    cum = np.cumsum(hist)
    n = int(cum[-1])
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
    # integer codes: median and MAD from the histogram (a few hundred bins, no sort); the
    # deviations are counted doubled so that a half-code median stays exact
    hist = np.bincount(sample.ravel())
    med = _histogram_median(hist)
    dev2 = np.abs(2 * np.arange(hist.size) - int(2 * med))
    mad = 0.5 * _histogram_median(np.bincount(dev2, weights=hist))
    return med, max(1.4826 * mad, 0.5)


def _top_code(frame: NDArray[np.generic], settings: StripeSettings) -> int:
    if settings.saturation_dn is not None:
        return settings.saturation_dn
    return 255 if frame.dtype == np.uint8 else 4095


def _empty() -> StripePoints:
    z = np.zeros(0)
    return StripePoints(z, z, z, z, flux_dn=z)


def _hot_columns(frame: NDArray[np.generic], level: float) -> tuple[int, int] | None:
    """The column span [first, last + 1) holding every pixel above `level`, or None."""
    hot = np.flatnonzero(frame.max(axis=0) > level)
    if hot.size == 0:
        return None
    return int(hot[0]), int(hot[-1]) + 1


@dataclass(frozen=True, eq=False)
class _Peaks:
    """The rows of one frame whose brightest pixel passes the peak threshold: row index, peak
    column, peak above background, the centroid window (n, 2k+1), whether a pixel outside the
    window exceeds half the peak; the frame's background, noise and top code. Grey values in
    float32, as the arithmetic is done."""

    rows: NDArray[np.intp]
    col: NDArray[np.intp]
    peak: NDArray[np.float32]
    win: NDArray[np.float32]
    multi: NDArray[np.bool_]
    bg: float
    sigma: float
    top: int


def _count_per_row(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    """True pixels per row of a 2-D mask (OpenCV's row sum: 3x numpy's count_nonzero)."""
    counts = cv2.reduce(mask.view(np.uint8), 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S)
    return np.asarray(counts, dtype=np.int32)[:, 0]


#: Pixel types OpenCV reduces; others (int32, int64, ...) go through numpy.
_CV_TYPES = (np.uint8, np.uint16, np.int16, np.float32, np.float64)


def _row_max(a: NDArray[np.generic]) -> NDArray[np.generic]:
    """Maximum of each row, shape=(H, 1) (OpenCV's row reduce: 3x numpy's on a column band)."""
    if a.dtype in _CV_TYPES:
        return np.asarray(cv2.reduce(a, 1, cv2.REDUCE_MAX)).reshape(-1, 1)  # type: ignore[arg-type]
    return a.max(axis=1, keepdims=True)


def _peaks(frame: NDArray[np.generic], s: StripeSettings) -> _Peaks | None:
    """Per row the brightest pixel (the first, as np.argmax) and its window, read only in the
    columns that hold a pixel above `level`, half the weakest accepted peak (plus the window):
    a dimmer pixel can be neither a row's peak nor a second peak, so the result is the full
    frame's, at a fraction of the cost (the stripe covers 5-20 % of a sweep frame's columns).
    The multi-peak test reads a row again only when a pixel above `level` lies outside its
    window."""
    w = frame.shape[1]
    bg, sigma = _background(frame)
    min_peak = max(s.min_peak_dn, s.noise_k * sigma)
    level = np.floor(bg + 0.5 * min_peak) - 1.0  # one code of slack: float32 half levels
    span = _hot_columns(frame, level)
    if span is None:
        return None
    k = s.half_window_px
    c0, c1 = max(span[0] - k, 0), min(span[1] + k, w)
    row_max = _row_max(frame[:, c0:c1])
    rows = np.flatnonzero(row_max[:, 0].astype(np.float32) - bg > min_peak)
    if rows.size == 0:
        return None
    r0 = int(rows[0])  # the band of rows with a peak: fewer rows at the ends of a sweep
    crop, row_max, rows = frame[r0 : int(rows[-1]) + 1, c0:c1], row_max[r0:], rows - r0
    col = np.argmax(crop == row_max[: crop.shape[0]], axis=1)[rows]
    peak = row_max[rows, 0].astype(np.float32) - bg
    at = col[:, None] + (c0 + np.arange(-k, k + 1))
    win = crop[rows[:, None], np.clip(at, 0, w - 1) - c0]
    # at the image border the window repeats the border pixel: count each pixel once here
    in_win = np.count_nonzero((win > level) & (at >= 0) & (at < w), axis=1)
    suspect = np.flatnonzero(_count_per_row(crop > level)[rows] > in_win)
    multi = np.zeros(rows.size, dtype=bool)
    if suspect.size:
        half = (bg + 0.5 * peak[suspect]).astype(crop.dtype)[:, None]
        above_row = np.count_nonzero(crop[rows[suspect]] > half, axis=1)
        multi[suspect] = above_row > np.count_nonzero(win[suspect] > half, axis=1)
    win_f = win.astype(np.float32)
    return _Peaks(rows + r0, col + c0, peak, win_f, multi, bg, sigma, _top_code(frame, s))


def _centroids(peaks: list[_Peaks | None], s: StripeSettings) -> list[StripePoints]:
    """The windowed centroids and rejections of every frame's peak rows, computed on all
    frames' rows at once (per frame the arrays are small: a call per frame would cost more in
    overhead than in arithmetic). Per-frame scalars enter as float32, as they did per frame."""
    real = [p for p in peaks if p is not None]
    if not real:
        return [_empty() for _ in peaks]
    counts = np.array([len(p.rows) for p in real])
    frame_of = np.repeat(np.arange(len(real)), counts)

    def per_row(values: list[float]) -> NDArray[np.float32]:
        return np.array(values, dtype=np.float32)[frame_of]

    bg = per_row([p.bg for p in real])
    three_sigma = per_row([3.0 * p.sigma for p in real])
    top = per_row([float(p.top) for p in real])
    peak = np.concatenate([p.peak for p in real])
    win = np.concatenate([p.win for p in real])
    multi = np.concatenate([p.multi for p in real])
    saturated = (win >= top[:, None]).any(axis=1)
    wts = np.clip(win - bg[:, None] - three_sigma[:, None], 0.0, None)
    # weight sum, first and second moments about the peak column in one product
    offs = np.arange(-s.half_window_px, s.half_window_px + 1, dtype=np.float64)
    moments = wts.astype(np.float64) @ np.column_stack([np.ones_like(offs), offs, offs**2])
    wsum = np.maximum(moments[:, 0], 1e-9)
    centre = moments[:, 1] / wsum
    width = np.sqrt(np.maximum(moments[:, 2] / wsum - centre**2, 0.0))
    edge_bright = np.maximum(win[:, 0], win[:, -1]) - bg > 0.5 * peak
    flux = (win - bg[:, None]).sum(axis=1, dtype=np.float64)
    wide = (width > s.max_width_px) | edge_bright
    good = ~(saturated | multi | wide) & (moments[:, 0] > 0)
    n = len(real)
    tallies = [
        np.bincount(frame_of[m], minlength=n)
        for m in (good, saturated, multi & ~saturated, wide & ~multi & ~saturated)
    ]
    cut = np.cumsum(tallies[0])[:-1]
    u = np.split(np.concatenate([p.col for p in real])[good] + centre[good], cut)
    v = np.split(np.concatenate([p.rows for p in real])[good].astype(np.float64), cut)
    pk = np.split(peak[good].astype(np.float64), cut)
    wd = np.split(width[good], cut)
    fx = np.split(flux[good], cut)
    n_sat, n_multi, n_wide = (t.tolist() for t in tallies[1:])
    out = iter(
        StripePoints(u[i], v[i], pk[i], wd[i], n_sat[i], n_multi[i], n_wide[i], fx[i])
        for i in range(n)
    )
    return [next(out) if p is not None else _empty() for p in peaks]


def extract_fast_sweep(
    frames: Sequence[NDArray[np.generic]] | NDArray[np.generic],
    settings: StripeSettings | None = None,
) -> list[StripePoints]:
    """`extract_fast` of every frame of a sweep (identical results), the per-row arithmetic
    done once for all frames."""
    s = settings or StripeSettings()
    return _centroids([_peaks(np.asarray(f), s) for f in frames], s)


def extract_fast(
    frame: NDArray[np.generic], settings: StripeSettings | None = None
) -> StripePoints:
    """Windowed grey centroid per row, background-subtracted; see the module docstring."""
    s = settings or StripeSettings()
    return _centroids([_peaks(frame, s)], s)[0]


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
        flux_dn=None if fast.flux_dn is None else fast.flux_dn[good],
    )


def extract_sweep(
    frames: Sequence[NDArray[np.generic]] | NDArray[np.generic],
    mode: str = "fast",
    settings: StripeSettings | None = None,
) -> list[StripePoints]:
    """`extract_stripe` of every frame of a sweep (the same points, faster)."""
    for f in frames:
        if np.ndim(f) != 2:
            raise ValueError(f"frame must be 2-D, got shape {np.shape(f)}")
    if mode not in ("fast", "precise"):
        raise ValueError(f"unknown stripe mode {mode!r} (fast, precise)")
    coarse = extract_fast_sweep(frames, settings)
    if mode == "fast":
        return coarse
    return [
        extract_precise(np.asarray(f), settings, c) for f, c in zip(frames, coarse, strict=True)
    ]


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
