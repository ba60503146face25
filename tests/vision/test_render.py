"""The renderer's own geometry is consistent: its truth is what the estimators are judged by."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fakes import render_sensor
from fakes.render import (
    Lighting,
    render_frames,
    render_sphere_sweep,
    sphere_hits,
)
from fakes.render_noise import NoiseSettings, _form, dark_frame
from fakes.render_plane import render_chessboard
from fakes.render_sensor import TrueSensor, _rays, _rays_of


def test_pixel_rays_invert_the_projection(true_sensor: TrueSensor) -> None:
    rays = true_sensor.pixel_rays
    v, u = np.mgrid[0:966:37, 0:1296:41]
    uv = true_sensor.project(rays[v, u] * 125.0)
    assert np.abs(uv - np.stack([u, v], axis=-1)).max() < 1e-8


def test_pixel_rays_read_from_the_cache_are_the_computed_ones(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A camera's rays are computed once a machine (the user's cache folder): read back, they
    are the computed ones to the bit, read-only; another camera has its own; a damaged file is
    computed again; a folder that cannot be written is no error. (A small camera: the same
    computation, 1/500 of the pixels.)"""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))

    def camera() -> TrueSensor:
        return TrueSensor(width_px=64, height_px=48, cx_px=31.5, cy_px=23.5)

    def other() -> TrueSensor:
        return dataclasses.replace(camera(), fx_px=camera().fx_px * 1.004, dist=camera().dist * 1.1)

    _rays_of.cache_clear()
    try:
        first = [camera().pixel_rays, other().pixel_rays]
        files = sorted((tmp_path / "cache" / "rvis").glob("pixel-rays-*.npy"))
        assert len(files) == 2
        files[0].write_bytes(b"damaged")
        _rays_of.cache_clear()
        computed: list[tuple[float, ...]] = []

        def counted(key: tuple[float, ...]) -> np.ndarray:
            computed.append(key)
            return _rays(key)

        # (the files' names come from the computation's source, read before this)
        monkeypatch.setattr(render_sensor, "_rays", counted)
        again = [camera().pixel_rays, other().pixel_rays]
        # the damaged file's camera computed again, the other one's rays read from its file
        assert _rays_of.cache_info().misses == 2 and len(computed) == 1
        for a, b, sensor in zip(first, again, (camera(), other()), strict=True):
            assert np.array_equal(a, b) and not b.flags.writeable and b.shape == (48, 64, 3)
            fields = (sensor.fx_px, sensor.fy_px, sensor.cx_px, sensor.cy_px, *sensor.dist)
            assert np.array_equal(b, _rays((*fields, 64.0, 48.0)))
            uv = sensor.project(b * 125.0)
            v, u = np.mgrid[0:48, 0:64]
            assert np.abs(uv - np.stack([u, v], axis=-1)).max() < 1e-8
        assert not np.array_equal(first[0], first[1])
        monkeypatch.setenv("XDG_CACHE_HOME", "/proc/no-such-folder")
        _rays_of.cache_clear()
        assert np.array_equal(camera().pixel_rays, first[0]) and len(computed) == 2
    finally:
        _rays_of.cache_clear()


def _bilinear(grid: np.ndarray, uv: np.ndarray) -> np.ndarray:
    u0 = np.clip(np.floor(uv[:, 0]).astype(int), 0, grid.shape[1] - 2)
    v0 = np.clip(np.floor(uv[:, 1]).astype(int), 0, grid.shape[0] - 2)
    fu, fv = (uv[:, 0] - u0)[:, None], (uv[:, 1] - v0)[:, None]
    return np.asarray(
        (1 - fv) * ((1 - fu) * grid[v0, u0] + fu * grid[v0, u0 + 1])
        + fv * ((1 - fu) * grid[v0 + 1, u0] + fu * grid[v0 + 1, u0 + 1])
    )


def test_true_stripe_lies_on_sphere_and_plane(
    true_sensor: TrueSensor, rng: np.random.Generator
) -> None:
    c = np.array([1.0, -2.0, 131.0])
    frames, _, truth = render_sphere_sweep(
        c, 15.0, true_sensor, rng, commands_v=np.array([-1.0, 0.0, 1.5])
    )
    assert frames.shape == (3, 966, 1296) and frames.dtype == np.uint8
    for k in range(3):
        uv = truth.stripe_uv[k]
        assert len(uv) > 100
        # back-project the true stripe pixels onto the true laser plane: they lie on the sphere
        rays = _bilinear(true_sensor.pixel_rays, uv)
        t = truth.plane_offsets_mm[k] / (rays @ truth.plane_normals[k])
        radius = np.linalg.norm(rays * t[:, None] - c, axis=1)
        assert np.median(np.abs(radius - 15.0)) < 1e-4  # interpolation error only
        # the image is bright where the truth says the stripe is
        rows = np.arange(200, 760, 40).astype(float)
        cols = np.rint(truth.stripe_columns(k, rows)).astype(int)
        rows_i = rows.astype(int)
        assert np.median(frames[k][rows_i, cols]) > 20


def test_noise_quantisation_and_saturation(
    true_sensor: TrueSensor, rng: np.random.Generator
) -> None:
    c = np.array([0.0, 0.0, 130.0])
    dim, _, _ = render_sphere_sweep(
        c, 15.0, true_sensor, rng, commands_v=np.array([0.0]), noise=NoiseSettings(bits=12)
    )
    hot, _, _ = render_sphere_sweep(
        c, 15.0, true_sensor, rng, commands_v=np.array([0.0]), light=Lighting(power=50.0)
    )
    assert dim.dtype == np.uint16 and dim.max() > 300
    assert np.count_nonzero(dim == 4095) < 20  # speckle peaks may touch the top, rarely
    assert hot.max() == 255 and np.count_nonzero(hot == 255) > 1000
    background = dim[0, :100, :100].astype(float)
    assert 10 < background.mean() < 40  # black level + ambient, in 12-bit DN
    assert background.std() > 1.0  # read noise is present


def test_chessboard_truth_projects_onto_the_corners(
    true_sensor: TrueSensor, rng: np.random.Generator
) -> None:
    import cv2

    T = np.eye(4)
    T[:3, 3] = [-10.0, -6.0, 122.0]
    frame8, corners, obj = render_chessboard(T, true_sensor, rng)
    frame = np.asarray(frame8, dtype=np.uint8)
    found, det = cv2.findChessboardCorners(frame, (9, 6))
    assert found
    det = cv2.cornerSubPix(
        frame, det, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    )
    det = det.reshape(-1, 2)
    if np.linalg.norm(det[0] - corners[0]) > np.linalg.norm(det[-1] - corners[0]):
        det = det[::-1]
    assert np.abs(det - corners).max() < 0.15
    assert obj.shape == (54, 3)


def test_sphere_box_loses_no_pixel(true_sensor: TrueSensor) -> None:
    """Casting rays only inside the sphere's image box finds exactly the pixels a full-frame
    cast finds, also for spheres cut by the frame's edge."""
    for c in ([0.0, 0.0, 130.0], [13.0, -10.0, 125.0], [-18.5, 13.5, 135.0], [30.0, 0.0, 128.0]):
        roi, X_roi = sphere_hits(true_sensor, np.array(c), 15.0)
        full, X_full = sphere_hits(true_sensor, np.array(c), 15.0, roi=False)
        np.testing.assert_array_equal(np.sort(roi), full)
        np.testing.assert_allclose(X_roi[np.argsort(roi)], X_full)


def test_dark_pixels_follow_the_noise_model(rng: np.random.Generator) -> None:
    """Dark pixels drawn from the quantile table have the digital-number distribution of the
    full model (Gaussian shot + read noise around the ambient level, gain, black level, rounding)
    that the lit box uses."""
    for noise in (NoiseSettings(), NoiseSettings(bits=12), NoiseSettings(shot_noise=False)):
        table = dark_frame((400, 500), noise, rng).astype(float).ravel()
        model = (
            _form(
                np.zeros((400, 500), np.float32),
                NoiseSettings(
                    speckle_contrast=0.0,
                    blur_sigma_px=0.0,
                    bits=noise.bits,
                    shot_noise=noise.shot_noise,
                ),
                rng,
            )
            .astype(float)
            .ravel()
        )
        top = (1 << noise.bits) - 1
        hist_t = np.bincount(table.astype(int), minlength=top + 1) / table.size
        hist_m = np.bincount(model.astype(int), minlength=top + 1) / model.size
        assert abs(table.mean() - model.mean()) < 0.01 * max(model.std(), 1.0)
        assert abs(table.std() / model.std() - 1) < 0.01
        assert np.abs(hist_t - hist_m).max() < 0.005


def test_tile_culling_changes_no_pixel(true_sensor: TrueSensor) -> None:
    """Skipping the tiles far from each laser plane renders exactly the same frames."""
    c = np.array([-6.0, 4.0, 127.0])
    idx, X = sphere_hits(true_sensor, c, 15.0)
    normals, offsets = true_sensor.laser_planes(np.linspace(-3.2, 3.2, 6))
    frames = [
        render_frames(
            true_sensor,
            idx,
            X,
            (X - c) / 15.0,
            normals,
            offsets,
            Lighting(ghost_gain=0.3),
            NoiseSettings(),
            np.random.default_rng(5),
            cull=cull,
        )
        for cull in (False, True)
    ]
    assert int(frames[0].max()) > 100
    np.testing.assert_array_equal(frames[0], frames[1])
