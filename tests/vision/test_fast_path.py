"""The faster sweep -> centre path against the code it replaced (tests/vision/reference_pipeline.py)
and against the renderer's truth: the same stripe points and rejections, the same fit, the same
centres. Stated tolerance: 1e-5 px and 1 nm (the stripe's noise is about 0.05 px, 20 um). On
rendered sweeps with the cases that exercise the region of interest (multi-peak ghost,
saturated glint, sphere cut by the image border, 12-bit noisy frames) and on random frames with
stripes at the image borders."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.render import Lighting, default_sweep_commands, render_sphere_sweep
from fakes.render_noise import NoiseSettings
from fakes.render_sensor import TrueSensor
from tests.vision.reference_pipeline import extract_fast_reference, fit_sphere_geometric_reference
from vision.measure import measure_sphere_from_sweep
from vision.sensor_model import SensorModel
from vision.spherefit import fit_sphere_geometric, fit_sphere_pratt
from vision.stripe import StripePoints, extract_fast, extract_sweep
from vision.triangulate import triangulate_sweep

COMMANDS = default_sweep_commands(10, 3.2)
# the replaced code summed the centroid weights in float32 (12-bit frames: about 1e-7 px off)
PX_TOL = 1e-5
MM_TOL = 1e-6  # 1 nm

CASES = {
    "default": (np.array([0.3, -0.2, 130.0]), None, None),
    "ghost": (np.array([0.0, 0.0, 130.0]), Lighting(ghost_gain=0.4), None),
    "glint": (np.array([0.0, 0.0, 130.0]), Lighting(glint_gain=20.0), None),
    "border": (np.array([18.0, 8.0, 130.0]), None, None),
    "12 bit noisy": (np.array([-2.0, 1.0, 128.0]), None, NoiseSettings(bits=12, read_noise_e=60.0)),
}


def _same_points(new: StripePoints, old: StripePoints) -> None:
    np.testing.assert_array_equal(new.v_px, old.v_px)
    for name in ("u_px", "peak_dn", "width_px"):
        np.testing.assert_allclose(getattr(new, name), getattr(old, name), rtol=0, atol=PX_TOL)
    assert (new.n_saturated, new.n_multi_peak, new.n_too_wide) == (
        old.n_saturated,
        old.n_multi_peak,
        old.n_too_wide,
    )


def _centre_before(stripes: list[StripePoints], cmds: np.ndarray, model: SensorModel) -> np.ndarray:
    """The certified-radius centre as the replaced fit computed it."""
    X, _ = triangulate_sweep(stripes, cmds, model)
    c0, r0 = fit_sphere_pratt(X)
    c_free, *_ = fit_sphere_geometric_reference(X, c0, r0, fixed_radius=False)
    c, *_ = fit_sphere_geometric_reference(X, c_free, 15.0, fixed_radius=True)
    return np.asarray(c)


@pytest.mark.parametrize("case", list(CASES))
def test_rendered_sweep_gives_the_same_points_and_centre_as_before(
    true_sensor: TrueSensor, perfect_model: SensorModel, case: str
) -> None:
    c_true, light, noise = CASES[case]
    rng = np.random.default_rng(7)
    frames, cmds, _ = render_sphere_sweep(
        c_true, 15.0, true_sensor, rng, commands_v=COMMANDS, light=light, noise=noise
    )
    before = [extract_fast_reference(f) for f in frames]
    after = extract_sweep(frames)
    for new, old in zip(after, before, strict=True):
        _same_points(new, old)
    assert sum(len(s) for s in after) > 1000  # not a vacuous comparison
    m = measure_sphere_from_sweep(frames, cmds, perfect_model)
    np.testing.assert_allclose(
        m.c_sensor_mm, _centre_before(before, cmds, perfect_model), atol=MM_TOL
    )
    assert np.abs(m.c_sensor_mm - c_true).max() < 0.008  # and right, against the renderer


def test_faster_fit_matches_the_replaced_fit(
    true_sensor: TrueSensor, perfect_model: SensorModel
) -> None:
    frames, cmds, _ = render_sphere_sweep(
        np.array([1.0, 0.5, 131.0]),
        15.0,
        true_sensor,
        np.random.default_rng(3),
        commands_v=COMMANDS,
    )
    X, _ = triangulate_sweep(extract_sweep(frames), cmds, perfect_model)
    c0, r0 = fit_sphere_pratt(X)
    for fixed, radius in ((False, r0), (True, 15.0)):
        new = fit_sphere_geometric(X, c0, radius, fixed_radius=fixed)
        old = fit_sphere_geometric_reference(X, c0, radius, fixed_radius=fixed)
        np.testing.assert_allclose(new[0], old[0], rtol=0, atol=MM_TOL)
        assert abs(new[1] - old[1]) < MM_TOL
        np.testing.assert_allclose(new[2], old[2], rtol=0, atol=MM_TOL)
        np.testing.assert_allclose(new[3], old[3], rtol=1e-6)
        assert new[4] == old[4]  # the same iterations


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int64])
def test_random_frames_with_stripes_at_the_borders(dtype: type) -> None:
    """Stripes from column 0 to the last, of random width, brightness and wander; second peaks,
    saturated rows, background noise of 2-40 codes; frames of random width."""
    rng = np.random.default_rng(11)
    top = 255 if dtype == np.uint8 else 4095  # int64: the numpy fallbacks
    rows = found = 0
    rejected = np.zeros(3, dtype=int)
    for _ in range(6):
        h, w = 60, int(rng.integers(20, 200))
        frames: list[np.ndarray] = []
        for _ in range(5):
            f = rng.integers(0, int(rng.integers(2, 40)), size=(h, w)).astype(np.float64)
            u = rng.choice([0.0, w - 1.0, rng.uniform(0, w)]) + rng.normal(0, rng.uniform(0, 9), h)
            sigma_px = rng.uniform(0.5, 4.0)
            stripe = np.exp(-0.5 * ((np.arange(w) - np.clip(u, 0, w - 1)[:, None]) / sigma_px) ** 2)
            f += top * rng.uniform(0.05, 1.2) * stripe
            ghost = rng.random(h) < 0.2
            f[ghost, rng.integers(0, w, ghost.sum())] += top * rng.uniform(0.1, 0.9)
            f[rng.random(h) < 0.05] = top
            frames.append(np.clip(np.rint(f), 0, top).astype(dtype))
        for frame, new in zip(frames, extract_sweep(frames), strict=True):
            old = extract_fast_reference(frame)
            _same_points(new, old)
            _same_points(extract_fast(frame), old)
            rows += h
            found += old.v_px.size
            rejected += (old.n_saturated, old.n_multi_peak, old.n_too_wide)
    # not vacuous: a third of the rows give a point, and every kind of rejection happens
    assert found > rows // 3 and np.all(rejected > 0)
