"""Image formation after the geometry: speckle, optical blur, shot and read noise, quantisation.

The input is the noise-free irradiance of one frame as a fraction of the full-well capacity
(float32, shape=(H, W)); the output the camera's digital numbers (uint8 or uint16 for 12 bit),
saturating at the top code. Speckle, blur and the per-pixel noise model are only computed
inside the lit region (plus a margin); the dark rest of the frame is drawn, pixel by pixel and
independently in every frame, from the exact distribution of a dark pixel's digital number
(ambient light, shot and read noise, black level, rounding, clipping) through a quantile table:
a frame with a thin stripe costs a few milliseconds instead of tens.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtri

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class NoiseSettings:
    """Camera and laser noise; defaults describe the simulated acA1300 with a 730 nm laser.

    speckle_contrast: 0 (none) .. 1 (fully developed); speckle_grain_px: Gaussian sigma of the
    pupil's coherence cell in pixels; blur_sigma_px: optical PSF sigma; full_well_e: electrons at
    the top code; read_noise_e: electrons RMS; black_level_dn: offset; bits: 8 or 12.
    """

    speckle_contrast: float = 0.6
    speckle_grain_px: float = 1.2
    blur_sigma_px: float = 0.7
    full_well_e: float = 10000.0
    read_noise_e: float = 15.0
    ambient_e: float = 40.0
    black_level_dn: float = 4.0
    bits: int = 8
    shot_noise: bool = True


#: Irradiance (fraction of full well) below which a pixel counts as dark: < 1 electron.
LIT_THRESHOLD = 1e-4


def margin_px(noise: NoiseSettings) -> int:
    """Margin around the lit pixels that speckle grain and blur may reach."""
    return int(4 * max(noise.blur_sigma_px, noise.speckle_grain_px)) + 2


def lit_box(img: F32, threshold: float, margin: int) -> tuple[slice, slice] | None:
    """Bounding box (row slice, column slice) of pixels above threshold, grown by margin."""
    rows = np.flatnonzero(img.max(axis=1) > threshold)
    if rows.size == 0:
        return None
    cols = np.flatnonzero(img[rows[0] : rows[-1] + 1].max(axis=0) > threshold)
    h, w = img.shape
    return (
        slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
        slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)),
    )


def speckle_field(shape: tuple[int, int], noise: NoiseSettings, rng: np.random.Generator) -> F32:
    """Multiplicative speckle of mean 1: |low-passed complex Gaussian|^2 mixed to the contrast."""
    re = rng.standard_normal(shape, dtype=np.float32)
    im = rng.standard_normal(shape, dtype=np.float32)
    s = noise.speckle_grain_px
    re_b = np.asarray(cv2.GaussianBlur(re, (0, 0), s), dtype=np.float32)
    im_b = np.asarray(cv2.GaussianBlur(im, (0, 0), s), dtype=np.float32)
    inten = re_b * re_b + im_b * im_b
    inten /= np.float32(max(float(inten.mean()), 1e-12))
    c = np.float32(noise.speckle_contrast)
    return np.asarray(1.0 + c * (inten - 1.0), dtype=np.float32)


@lru_cache(maxsize=16)
def _dark_quantiles(noise: NoiseSettings) -> NDArray[np.integer[Any]]:
    """Digital number of a dark pixel at each of 65536 equally spaced quantiles.

    A dark pixel holds ambient_e electrons plus Gaussian noise (shot noise of the ambient light
    and read noise, as in `form_image`), then gain, black level, rounding and clipping: a
    monotonic map of one standard normal variable, so the quantiles of the digital number are
    the map of the normal quantiles. Sampling a uniform 16-bit index reproduces the distribution
    to 1/65536 in probability (tails beyond 4.2 sigma fold onto the last table entry).
    """
    z = ndtri((np.arange(65536) + 0.5) / 65536.0)
    sigma = (
        np.sqrt(noise.ambient_e + noise.read_noise_e**2)
        if noise.shot_noise
        else (noise.read_noise_e)
    )
    top = (1 << noise.bits) - 1
    dn = (noise.ambient_e + sigma * z) * (top / noise.full_well_e) + noise.black_level_dn
    out = np.clip(np.rint(dn), 0, top).astype(np.uint8 if noise.bits <= 8 else np.uint16)
    out.flags.writeable = False
    return out


def dark_frame(
    shape: tuple[int, int], noise: NoiseSettings, rng: np.random.Generator
) -> NDArray[np.integer[Any]]:
    """A frame without any laser light: independent dark pixels (see `_dark_quantiles`)."""
    idx = rng.integers(0, 65536, size=shape, dtype=np.uint16)
    return np.take(_dark_quantiles(noise), idx)


def form_image_in_box(
    shape: tuple[int, int],
    box: tuple[slice, slice] | None,
    irr_box: F32,
    noise: NoiseSettings,
    rng: np.random.Generator,
) -> NDArray[np.integer[Any]]:
    """A frame of `shape` whose irradiance is `irr_box` inside `box` (row and column slices,
    irr_box of the box's shape) and zero outside: the full image formation inside the box,
    dark pixels outside. The box must include the speckle and blur margin."""
    out = dark_frame(shape, noise, rng)
    if box is not None:
        out[box] = _form(np.asarray(irr_box, dtype=np.float32), noise, rng)
    return out


def form_image(
    irr: F32, noise: NoiseSettings, rng: np.random.Generator
) -> NDArray[np.integer[Any]]:
    """Irradiance (fraction of full well, shape=(H, W)) -> digital frame (uint8 or uint16).

    Pixels outside the lit box (irradiance < 1e-4 of full well, i.e. < 1 electron, plus the
    speckle and blur margin) are formed as dark pixels."""
    img = np.asarray(irr, dtype=np.float32)
    box = lit_box(img, LIT_THRESHOLD, margin_px(noise))
    shape = (img.shape[0], img.shape[1])
    return form_image_in_box(shape, box, img[box] if box is not None else img[:0, :0], noise, rng)


def _form(irr: F32, noise: NoiseSettings, rng: np.random.Generator) -> NDArray[np.integer[Any]]:
    """The full image formation of a lit region (speckle, blur, shot and read noise, gain,
    black level, quantisation with saturation)."""
    img = irr.astype(np.float32, copy=True)
    if noise.speckle_contrast > 0:
        img *= speckle_field((img.shape[0], img.shape[1]), noise, rng)
    if noise.blur_sigma_px > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), noise.blur_sigma_px), dtype=np.float32)
    electrons = img * np.float32(noise.full_well_e) + np.float32(noise.ambient_e)
    sigma = np.float32(noise.read_noise_e)
    if noise.shot_noise:
        sigma = np.sqrt(electrons + sigma * sigma)
    electrons += sigma * rng.standard_normal(img.shape, dtype=np.float32)
    top = (1 << noise.bits) - 1
    dn = electrons * np.float32(top / noise.full_well_e) + np.float32(noise.black_level_dn)
    np.clip(np.rint(dn), 0, top, out=dn)
    return dn.astype(np.uint8 if noise.bits <= 8 else np.uint16)
