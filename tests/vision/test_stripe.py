"""Stripe extraction against the renderer's true stripe line."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.render import Lighting, SweepTruth, render_sphere_sweep
from fakes.render_noise import NoiseSettings, form_image
from fakes.render_sensor import TrueSensor
from vision.stripe import extract_stripe

CLEAN = NoiseSettings(speckle_contrast=0.0)


def _sweep(
    sensor: TrueSensor,
    rng: np.random.Generator,
    noise: NoiseSettings | None = None,
    light: Lighting | None = None,
) -> tuple[np.ndarray, SweepTruth]:
    frames, _, truth = render_sphere_sweep(
        np.array([0.5, 0.3, 129.0]),
        15.0,
        sensor,
        rng,
        commands_v=np.array([-1.5, 0.0, 1.5]),
        noise=noise,
        light=light,
    )
    return frames, truth


def _errors(frames: np.ndarray, truth: SweepTruth, mode: str) -> np.ndarray:
    errs = []
    for k, frame in enumerate(frames):
        pts = extract_stripe(frame, mode)
        e = pts.u_px - truth.stripe_columns(k, pts.v_px)
        errs.append(e[np.isfinite(e)])
    return np.concatenate(errs)


@pytest.mark.parametrize("mode", ["fast", "precise"])
def test_sub_pixel_without_speckle(
    true_sensor: TrueSensor, rng: np.random.Generator, mode: str
) -> None:
    frames, truth = _sweep(true_sensor, rng, noise=CLEAN)
    e = _errors(frames, truth, mode)
    assert len(e) > 1500
    assert abs(float(np.mean(e))) < 0.03
    assert float(np.std(e)) < 0.12


@pytest.mark.parametrize("mode", ["fast", "precise"])
def test_speckle_is_noise_not_bias(
    true_sensor: TrueSensor, rng: np.random.Generator, mode: str
) -> None:
    frames, truth = _sweep(true_sensor, rng)
    e = _errors(frames, truth, mode)
    assert len(e) > 1500
    gross = np.abs(e) > 3.0  # near the limb the stripe runs along the rows: the fit's outliers
    assert gross.mean() < 0.02
    assert abs(float(np.mean(e[~gross]))) < 0.05
    assert 0.2 < float(np.std(e[~gross])) < 1.2  # the speckle floor: ~15-35 um per point


def test_blank_frame_gives_no_points(rng: np.random.Generator) -> None:
    frame = form_image(np.zeros((966, 1296), np.float32), NoiseSettings(), rng)
    for mode in ("fast", "precise"):
        assert len(extract_stripe(frame, mode)) == 0


def test_saturated_rows_are_rejected(true_sensor: TrueSensor, rng: np.random.Generator) -> None:
    frames, _ = _sweep(true_sensor, rng, light=Lighting(power=40.0))
    pts = extract_stripe(frames[1])
    assert pts.n_saturated > 500 and len(pts) < 50


def test_two_stripes_are_rejected_not_averaged(
    true_sensor: TrueSensor, rng: np.random.Generator
) -> None:
    frames, truth = _sweep(true_sensor, rng, noise=CLEAN, light=Lighting(ghost_gain=1.0))
    pts = extract_stripe(frames[1])
    assert pts.n_multi_peak > 500
    e = pts.u_px - truth.stripe_columns(1, pts.v_px)
    # rows kept are those where the ghost fell off the sphere: they are on the true stripe
    assert np.all(np.abs(e[np.isfinite(e)]) < 0.5)


def test_wrong_shape_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="2-D"):
        extract_stripe(np.zeros((2, 3, 4), np.uint8))
    with pytest.raises(ValueError, match="unknown stripe mode"):
        extract_stripe(np.zeros((3, 4), np.uint8), "magic")


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_background_from_the_histogram_equals_the_median(
    rng: np.random.Generator, dtype: type[np.unsignedinteger]
) -> None:
    """The background level and noise come from a histogram (8x faster than a sort): the very
    numbers np.median gives, on odd and even sample sizes and half-code medians."""
    from vision.stripe import _background

    top = 255 if dtype == np.uint8 else 4095
    for k in range(60):
        shape = (int(rng.integers(20, 200)), int(rng.integers(20, 200)))
        frame = rng.normal(20 + k, 1 + k % 7, size=shape).clip(0, top).astype(dtype)
        sample = frame[::7, ::9].astype(np.float32).ravel()
        med = float(np.median(sample))
        mad = float(np.median(np.abs(sample - med)))
        assert _background(frame) == (med, max(1.4826 * mad, 0.5))
