"""Body features from stripe profiles: holes, slots and surface points recovered against the
simulated body's truth (fakes.body draws the profiles with its own geometry), and every refusal
typed. The sweeps are the views' (app.inspect.views.sweep_commands) on the default sensor."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from fakes.body import (
    BodyShop,
    BuildProcess,
    GeometricSensor,
    NominalFeature,
    TrueFeature,
    feature_profiles,
)
from fakes.render_sensor import TrueSensor, default_true_sensor
from vision.errors import FeatureRefused
from vision.features import FeatureFit, measure_feature
from vision.sensor_model import default_sensor_model
from vision.sheet import Plane, edge_points

F64 = NDArray[np.float64]
SEEDS = range(8)
WORKING_MM = 120.0


@pytest.fixture(scope="module")
def sensor() -> TrueSensor:
    return default_true_sensor()


def _pose(rng: np.random.Generator) -> F64:
    """T_part_sensor: the sensor looking down at the origin from the working distance, off by
    a tenth of a degree and tenths of a millimetre (a view planned on a calibrated model is within
    0.1 mm of the truth; the robot stops within 0.07 mm)."""
    w = rng.normal(0.0, 0.002, 3)
    angle = float(np.linalg.norm(w))
    k = w / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    T = np.eye(4)
    T[:3, :3] = R @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = np.array([0.0, 0.0, WORKING_MM]) + rng.normal(0.0, 0.3, 3)
    return T


def _commands(x_from: float, x_to: float, n: int) -> F64:
    lm = default_sensor_model().laser
    grid = np.linspace(-6.0, 6.0, 1201)
    normals, offsets = lm.planes(grid)
    x_at = (offsets - normals[:, 2] * WORKING_MM) / normals[:, 0]
    order = np.argsort(x_at)
    out: F64 = np.interp(np.linspace(x_from, x_to, n), x_at[order], grid[order])
    return out


def _measure(
    sensor: TrueSensor,
    nf: NominalFeature,
    seed: int,
    *,
    span: tuple[float, float] | None = None,
    frames: int = 40,
    nominal_size: tuple[float, ...] | None = None,
) -> tuple[FeatureFit, TrueFeature]:
    rng = np.random.default_rng([seed, 1])
    true = BodyShop([nf], BuildProcess(seed=seed)).body(seed).features[nf.id]
    T = _pose(rng)
    half = 0.5 * max(nf.size_mm, default=10.0) + 3.0
    lo, hi = span or (-half, half)
    planes = sensor.laser_planes(_commands(lo, hi, frames))
    geo = GeometricSensor(sensor.fy_px, sensor.cy_px, sensor.height_px, 18.5 / 130.0)
    profiles = feature_profiles(true, np.eye(4), T, planes, geo, rng)
    in_part = [p @ T[:3, :3].T + T[:3, 3] for p in profiles]
    size = nominal_size if nominal_size is not None else nf.size_mm
    fit = measure_feature(nf.kind, in_part, nf.position_mm, nf.normal, size, nf.axis)
    return fit, true


def _hole(d_mm: float = 10.0) -> NominalFeature:
    return NominalFeature(
        "H1", "hole", np.zeros(3), np.array([0.0, 0.0, 1.0]), np.zeros(3), (d_mm,)
    )


def _slot() -> NominalFeature:
    axis = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    return NominalFeature("S1", "slot", np.zeros(3), np.array([0.0, 0.0, 1.0]), axis, (8.0, 20.0))


@pytest.mark.parametrize("d_mm", [6.0, 12.0, 20.0])
def test_a_hole_is_found_where_it_is_built(sensor: TrueSensor, d_mm: float) -> None:
    errs, size_errs = [], []
    for seed in SEEDS:
        fit, true = _measure(sensor, _hole(d_mm), seed)
        errs.append(np.linalg.norm(fit.centre_mm - true.position_mm))
        size_errs.append(fit.size_mm[0] - true.size_mm[0])
        assert abs(float(fit.normal @ true.normal)) > 1 - 1e-5
        assert fit.coverage >= 0.7 and fit.n_edge_points >= 30
    # the sensor's noise is 20 um along the ray per point: tens of edge points average it
    assert max(errs) < 0.012
    assert max(np.abs(size_errs)) < 0.012
    # the half step past the last point on the sheet leaves no bias on the size
    assert abs(float(np.mean(size_errs))) < 0.004


def test_a_slot_is_found_with_its_axis_width_and_length(sensor: TrueSensor) -> None:
    for seed in SEEDS:
        fit, true = _measure(sensor, _slot(), seed, span=(-14.0, 14.0), frames=48)
        assert np.linalg.norm(fit.centre_mm - true.position_mm) < 0.015
        assert abs(fit.size_mm[0] - true.size_mm[0]) < 0.015
        assert abs(fit.size_mm[1] - true.size_mm[1]) < 0.02
        assert abs(float(fit.axis @ true.axis)) > np.cos(np.radians(0.2))


def test_a_surface_point_is_the_sheet_along_the_nominal_normal(sensor: TrueSensor) -> None:
    nf = NominalFeature("P1", "surface", np.zeros(3), np.array([0.0, 0.0, 1.0]), np.zeros(3), ())
    for seed in SEEDS:
        fit, true = _measure(sensor, nf, seed, span=(-5.0, 5.0), frames=10)
        # the built sheet moved along its normal; where the nominal normal meets it
        want = float(true.position_mm @ true.normal) / float(true.normal[2])
        assert abs(fit.deviation_mm - want) < 0.005


def test_a_sweep_over_half_the_hole_is_refused_for_its_coverage(sensor: TrueSensor) -> None:
    with pytest.raises(FeatureRefused) as info:
        _measure(sensor, _hole(12.0), 1, span=(-9.0, 0.5), frames=30)
    assert info.value.reason == "edge_coverage"


def test_a_sparse_sweep_is_refused_for_too_few_edge_points(sensor: TrueSensor) -> None:
    with pytest.raises(FeatureRefused) as info:
        _measure(sensor, _hole(6.0), 2, frames=4)
    assert info.value.reason == "edge_points"


def test_the_wrong_feature_is_refused_for_its_size(sensor: TrueSensor) -> None:
    with pytest.raises(FeatureRefused) as info:
        _measure(sensor, _hole(10.0), 3, nominal_size=(16.0,))
    assert info.value.reason == "size"
    assert "another feature" in str(info.value)


def test_points_that_are_no_sheet_are_refused_for_the_plane() -> None:
    rng = np.random.default_rng(5)
    xy = rng.uniform(-10, 10, (3000, 2))
    bumpy = np.column_stack([xy, 0.2 * np.sin(xy[:, 0])])  # a corrugated sheet
    profiles = [bumpy[i::30] for i in range(30)]
    with pytest.raises(FeatureRefused) as info:
        measure_feature("hole", profiles, np.zeros(3), np.array([0.0, 0.0, 1.0]), (8.0,))
    assert info.value.reason == "plane"


def test_no_points_is_refused() -> None:
    with pytest.raises(FeatureRefused) as info:
        measure_feature("hole", [np.zeros((0, 3))], np.zeros(3), np.array([0, 0, 1.0]), (8.0,))
    assert info.value.reason == "no_points"
    with pytest.raises(ValueError, match="kind"):
        measure_feature("stud", [np.ones((5, 3))], np.zeros(3), np.array([0, 0, 1.0]), (8.0,))


def _lit_profile(dark_at: int | None = None) -> F64:
    """One stripe's profile with its light (vision.triangulate.triangulate_profiles's columns)
    across an opening from y = 0 to y = 2 mm in the sheet z = 0, a row every 28 um, the
    stripe's width along its image row (0.02, 0, 0.05) mm: the face's rows (flux 100) up to
    y = -0.018; its last row cut across the stripe by the edge (70 % of its light, its centre
    0.3 widths towards the lit side); past the edge a row cut more (40 %, 0.8 widths: its centre
    in the opening) and the blur's dim copy of the last one (15 %, centred); on the far side the
    bore's wall lit 0.1 mm below the face, then the face from y = 2.012. dark_at: a face row
    that many rows in from the edge darkened to 30 % (the speckle)."""
    step, width_mm = 0.028, np.array([0.02, 0.0, 0.05])

    def row(y: float, flux: float, shift: float = 0.0, below_mm: float = 0.0) -> F64:
        at = np.array([0.0, y, -below_mm]) + shift * width_mm
        return np.r_[at, width_mm, flux]

    near = [row(-0.018 - k * step, 30.0 if k == dark_at else 100.0) for k in range(49, 0, -1)]
    cut = [row(-0.018, 70.0, 0.3), row(0.010, 40.0, 0.8), row(0.038, 15.0)]
    far = [row(1.984, 90.0, below_mm=0.1)] + [row(2.012 + k * step, 100.0) for k in range(50)]
    return np.array(near + cut + far)


def test_the_edge_is_where_the_stripe_s_rows_stop_being_half_lit() -> None:
    plane = Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, 100)
    lit = edge_points([_lit_profile()], plane)
    # the last half-lit row, moved along its image row back onto the face, plus half a row;
    # the wall's row is lit but no cut moves a row that far below the face
    assert np.allclose(lit, [[0.0, -0.004, 0.0], [0.0, 1.998, 0.0]], atol=1e-9)
    # the points alone: the run ends at the blur's copy, 52 um into the opening, and starts
    # on the wall, 28 um into it
    alone = edge_points([_lit_profile()[:, :3]], plane)
    assert np.allclose(alone[:, 1], [0.052, 1.970], atol=1e-9)
    # a row the speckle darkens inside the run counts against the rows past it (as one it
    # brightens past the edge counts for them): the edge one row in
    darkened = edge_points([_lit_profile(dark_at=5)], plane)
    assert np.allclose(darkened[:, 1], [-0.032, 1.998], atol=1e-9)


@pytest.mark.parametrize("lit", [False, True])
def test_a_sweeps_edge_points_are_each_profiles_own(lit: bool) -> None:
    """edge_points takes a sweep's profiles at once: each profile's steps, median and runs are
    its own (no step from one profile's last point to the next one's first), in the profiles'
    order, whatever profiles with too few points on the face (none, 3) sit between them."""
    plane = Plane(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, 100)
    rng = np.random.default_rng(5)
    base = _lit_profile() if lit else _lit_profile()[:, :3]
    profiles = []
    for k in range(6):
        p = base.copy()
        p[:, 0] += k * 0.5
        p[:, 2] += rng.normal(0.0, 0.003, len(p))  # each its own scatter and so its own median
        profiles.append(p[:: 1 + k % 2])  # every other row: another step
    profiles[2:2] = [base[:0], base[:3]]
    each = [edge_points([p], plane) for p in profiles]
    assert [len(e) for e in each] == [2, 2, 0, 0, 2, 2, 2, 2]
    assert np.array_equal(edge_points(profiles, plane), np.concatenate(each))
