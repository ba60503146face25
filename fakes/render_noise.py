"""Image formation after the geometry: speckle, optical blur, shot and read noise, quantisation.

The input is the noise-free irradiance of one frame as a fraction of the full-well capacity
(float32, shape=(H, W)); the output the camera's digital numbers (uint8 or uint16 for 12 bit),
saturating at the top code. Speckle and blur are only computed inside the lit region (plus a
margin) so that dark frames cost only the read noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

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


def lit_box(img: F32, threshold: float, margin: int) -> tuple[slice, slice] | None:
    """Bounding box (row slice, column slice) of pixels above threshold, grown by margin."""
    rows = np.flatnonzero(img.max(axis=1) > threshold)
    if rows.size == 0:
        return None
    cols = np.flatnonzero(img[rows[0] : rows[-1] + 1].max(axis=0) > threshold)
    h, w = img.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)))


def speckle_field(shape: tuple[int, int], noise: NoiseSettings,
                  rng: np.random.Generator) -> F32:
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


def form_image(irr: F32, noise: NoiseSettings, rng: np.random.Generator
               ) -> NDArray[np.integer[Any]]:
    """Irradiance (fraction of full well, shape=(H, W)) -> digital frame (uint8 or uint16)."""
    img = irr.astype(np.float32, copy=True)
    margin = int(4 * max(noise.blur_sigma_px, noise.speckle_grain_px)) + 2
    box = lit_box(img, 1e-4, margin)
    if box is not None:
        crop = img[box]
        if noise.speckle_contrast > 0:
            crop *= speckle_field((crop.shape[0], crop.shape[1]), noise, rng)
        if noise.blur_sigma_px > 0:
            crop[...] = cv2.GaussianBlur(crop, (0, 0), noise.blur_sigma_px)
    electrons = img * np.float32(noise.full_well_e) + np.float32(noise.ambient_e)
    sigma = np.float32(noise.read_noise_e)
    if noise.shot_noise:
        sigma = np.sqrt(electrons + sigma * sigma)
    electrons += sigma * rng.standard_normal(img.shape, dtype=np.float32)
    top = (1 << noise.bits) - 1
    dn = electrons * np.float32(top / noise.full_well_e) + np.float32(noise.black_level_dn)
    np.clip(np.rint(dn), 0, top, out=dn)
    return dn.astype(np.uint8 if noise.bits <= 8 else np.uint16)
