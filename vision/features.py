"""Body features from the stripe profiles of one sweep: round holes, slots and surface points.

A hole or slot: the sheet's plane from the stripe points around it (`vision.sheet.fit_plane`),
the edge points where the stripes break (`vision.sheet.edge_points`), projected onto that plane
and fitted there: a circle (centre, diameter) or a slot primitive, a stadium (centre, axis,
width, length). A surface point: the local plane of the points around the nominal point, and
the point where the nominal normal through the nominal point meets it.

The geometric fits are scipy.optimize.least_squares (trust region, a few hundred points, five
unknowns at most): it converges from the algebraic start in a few iterations and its Jacobian
at the solution gives the fit's own covariance, which the caller folds into the value's
uncertainty. A circle starts from Kasa's algebraic fit (unbiased enough on a full outline; the
bias REFERENCE.md names is a small cap's), a slot from the nominal axis and size.

A fit that fails a check is refused with a typed reason (`FeatureRefused`), never a number:
too few edge points, too little of the outline covered, a sheet whose points are not a plane,
edge points that do not lie on the primitive, a size far from nominal (the wrong feature).
All inputs and outputs in one frame, the caller's (mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from vision.errors import FeatureRefused
from vision.sheet import LIT_COLUMNS, Plane, SheetSettings, edge_points, fit_plane

F64 = NDArray[np.float64]
KINDS = ("hole", "slot", "surface")
#: the outline's coverage is counted in this many angle bins about the centre
COVERAGE_BINS = 36


@dataclass(frozen=True)
class FeatureSettings:
    """Limits that refuse a feature [mm]: min_edge_points; min_coverage (share of the
    outline's angle bins holding an edge point); max_fit_rms_mm (edge points about the fitted
    primitive); max_size_dev_mm (fitted size against nominal: beyond it, another feature);
    search_margin_mm (edge points count within the nominal outline's reach plus this);
    surface_radius_mm (a surface point's local plane from the points within it);
    min_surface_points."""

    min_edge_points: int = 16
    min_coverage: float = 0.6
    max_fit_rms_mm: float = 0.05
    max_size_dev_mm: float = 1.0
    search_margin_mm: float = 3.0
    surface_radius_mm: float = 5.0
    min_surface_points: int = 50
    sheet: SheetSettings = field(default_factory=SheetSettings)


@dataclass(frozen=True)
class FeatureFit:
    """One measured feature. centre_mm (3,) on the top face; normal (3,) of the sheet;
    size_mm: (diameter,) of a hole, (width, length) of a slot, () of a surface point;
    axis (3,) a slot's long axis (zeros otherwise); deviation_mm: a surface point's distance
    from the nominal point along the nominal normal (0 otherwise); cov_centre_mm2 (3, 3) the
    fit's own covariance of the centre; sd_size_mm per size; n_edge_points, coverage,
    plane_rms_mm, fit_rms_mm: the quality."""

    kind: str
    centre_mm: F64
    normal: F64
    size_mm: tuple[float, ...]
    axis: F64
    deviation_mm: float
    cov_centre_mm2: F64
    sd_size_mm: tuple[float, ...]
    n_edge_points: int
    coverage: float
    plane_rms_mm: float
    fit_rms_mm: float


@dataclass(frozen=True)
class FeaturePoints:
    """What a feature's fit uses, taken from its sweep's profiles (`extract_points`): sheet_mm
    (n, 3) points of the sheet on its plane, at most SHEET_SAMPLE taken evenly (a plane from
    a few hundred points is as good as from tens of thousands: the sensor's noise is averaged
    to a micrometre either way); edges_mm (m, 3) the edge points (none for a surface point).
    Small enough to store with the body (a few kilobytes), and the whole input of the fit: a
    feature is computed again from them with other parameters (`transformed`, `fit_feature`)."""

    sheet_mm: F64
    edges_mm: F64

    def transformed(self, T: F64) -> FeaturePoints:
        """The points mapped by the pose T (4, 4) (from the sensor frame to the part frame)."""
        R, t = T[:3, :3], T[:3, 3]
        return FeaturePoints(self.sheet_mm @ R.T + t, self.edges_mm @ R.T + t)


#: the most sheet points a FeaturePoints keeps
SHEET_SAMPLE = 600


def measure_feature(
    kind: str,
    profiles: Sequence[F64],
    nominal_mm: F64,
    normal: F64,
    size_mm: Sequence[float],
    axis: F64 | None = None,
    settings: FeatureSettings | None = None,
) -> FeatureFit:
    """Measure a feature of `kind` (KINDS) from its sweep's profiles (each (n_i, 3) points
    ordered along the stripe, or (n_i, 7) points with their light:
    vision.triangulate.triangulate_profiles), near its nominal centre nominal_mm (3,) with
    nominal normal (3,) and nominal size (hole: diameter; slot: width, length; surface: none)
    and a slot's nominal long axis (3,): `fit_feature` of `extract_points`. Raises
    FeatureRefused (typed reason) or ValueError for a wrong kind."""
    points = extract_points(kind, profiles, nominal_mm, normal, size_mm, settings)
    return fit_feature(kind, points, nominal_mm, normal, size_mm, axis, settings)


def extract_points(
    kind: str,
    profiles: Sequence[F64],
    nominal_mm: F64,
    normal: F64,
    size_mm: Sequence[float],
    settings: FeatureSettings | None = None,
) -> FeaturePoints:
    """The sheet's points and the edge points of a feature from its profiles (arguments as
    `measure_feature`'s, in the profiles' frame). Raises FeatureRefused (no_points, plane,
    edge_points) or ValueError for a wrong kind."""
    s = settings or FeatureSettings()
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    nominal_mm, normal = np.asarray(nominal_mm, float), _unit(np.asarray(normal, float))
    profs = [_profile(p) for p in profiles]
    if sum(len(p) for p in profs) == 0:
        raise FeatureRefused("no_points", "the sweep gave no stripe point")
    if kind == "surface":
        pts = np.concatenate([p[:, :3] for p in profs])
        local = pts[_radial(pts, nominal_mm, normal) <= s.surface_radius_mm]
        plane = fit_plane(local, normal, _surface_sheet(s))
        on = local[np.abs(plane.distance_mm(local)) <= _surface_sheet(s).plane_tol_mm]
        return FeaturePoints(_sample(on), np.zeros((0, 3)))
    reach = 0.5 * max(size_mm) + s.search_margin_mm
    near = _near(profs, nominal_mm, normal, reach + 8.0)
    every = np.concatenate([p[:, :3] for p in near])
    plane = fit_plane(every, normal, s.sheet)
    edges = edge_points(near, plane, s.sheet)
    edges = edges[_radial(edges, nominal_mm, normal) <= reach]
    if len(edges) < s.min_edge_points:
        raise FeatureRefused(
            "edge_points", f"{len(edges)} edge points, at least {s.min_edge_points}"
        )
    on = every[np.abs(plane.distance_mm(every)) <= s.sheet.plane_tol_mm]
    return FeaturePoints(_sample(on), edges)


def fit_feature(
    kind: str,
    points: FeaturePoints,
    nominal_mm: F64,
    normal: F64,
    size_mm: Sequence[float],
    axis: F64 | None = None,
    settings: FeatureSettings | None = None,
) -> FeatureFit:
    """The feature fitted to its points (arguments as `measure_feature`'s, in the points'
    frame). Raises FeatureRefused (plane, edge_coverage, fit, size)."""
    s = settings or FeatureSettings()
    nominal_mm, normal = np.asarray(nominal_mm, float), _unit(np.asarray(normal, float))
    if kind == "surface":
        return _surface_point(points.sheet_mm, nominal_mm, normal, s)
    sample = SheetSettings(
        s.sheet.plane_tol_mm, s.sheet.max_plane_rms_mm, min(s.sheet.min_plane_points, 50)
    )
    plane = fit_plane(points.sheet_mm, normal, sample)
    edges = points.edges_mm
    uv = plane.to_2d(edges, nominal_mm)
    size: tuple[float, ...]
    sd_size: tuple[float, ...]
    if kind == "hole":
        params, cov, rms = _fit_circle(uv)
        size, sd_size = (2.0 * float(params[2]),), (2.0 * float(np.sqrt(cov[2, 2])),)
        axis3 = np.zeros(3)
    else:
        a = _unit(np.asarray(axis, float)) if axis is not None else plane.basis()[0]
        params, cov, rms = _fit_slot(
            uv, plane.to_2d(nominal_mm[None] + a[None], nominal_mm)[0], size_mm
        )
        size = (float(params[3]), float(params[4]))
        sd_size = (float(np.sqrt(cov[3, 3])), float(np.sqrt(cov[4, 4])))
        e1, e2 = plane.basis()
        axis3 = np.cos(params[2]) * e1 + np.sin(params[2]) * e2
        axis3 = axis3 if axis3 @ a >= 0 else -axis3
    _check_fit(uv, params[:2], rms, size, size_mm, s)
    centre = plane.from_2d(params[None, :2], nominal_mm)[0]
    return FeatureFit(
        kind,
        centre,
        plane.normal,
        size,
        axis3,
        0.0,
        _lift(plane, cov[:2, :2]),
        sd_size,
        len(edges),
        _coverage(uv - params[:2]),
        plane.rms_mm,
        rms,
    )


def _check_fit(
    uv: F64,
    centre: F64,
    rms: float,
    size: tuple[float, ...],
    nominal: Sequence[float],
    s: FeatureSettings,
) -> None:
    cover = _coverage(uv - centre)
    if cover < s.min_coverage:
        raise FeatureRefused(
            "edge_coverage",
            f"{cover:.0%} of the outline has edge points, at least {s.min_coverage:.0%}",
        )
    if rms > s.max_fit_rms_mm:
        raise FeatureRefused(
            "fit",
            f"the edge points scatter {rms:.3f} mm about the fit (at most {s.max_fit_rms_mm:g} mm)",
        )
    worst = max(abs(a - b) for a, b in zip(size, nominal, strict=True))
    if worst > s.max_size_dev_mm:
        raise FeatureRefused(
            "size",
            f"size {'/'.join(f'{v:.2f}' for v in size)} mm against the nominal"
            f" {'/'.join(f'{v:g}' for v in nominal)} mm (at most {s.max_size_dev_mm:g} mm off):"
            " another feature",
        )


def _surface_sheet(s: FeatureSettings) -> SheetSettings:
    """A surface point's plane: a patch may curve gently, so its points are taken within a
    wider band of the plane."""
    return SheetSettings(
        plane_tol_mm=s.sheet.plane_tol_mm * 3,
        max_plane_rms_mm=s.sheet.max_plane_rms_mm,
        min_plane_points=s.min_surface_points,
    )


def _surface_point(points: F64, nominal: F64, normal: F64, s: FeatureSettings) -> FeatureFit:
    plane = fit_plane(points, normal, _surface_sheet(s))
    cos = float(plane.normal @ normal)
    t = float((plane.point_mm - nominal) @ plane.normal) / cos
    var = plane.rms_mm**2 / plane.n_inliers / cos**2
    cov = var * np.outer(normal, normal)
    return FeatureFit(
        "surface", nominal + t * normal, plane.normal, (), np.zeros(3), t, cov, (), 0, 1.0,
        plane.rms_mm, plane.rms_mm,
    )  # fmt: skip


def _profile(p: F64) -> F64:
    """A profile as an array: (n, 3) points, or (n, LIT_COLUMNS) points with their light."""
    a = np.asarray(p, float)
    if a.ndim == 2 and a.shape[1] == LIT_COLUMNS:
        return a
    out: F64 = a.reshape(-1, 3)
    return out


def _sample(points: F64) -> F64:
    """At most SHEET_SAMPLE of the points, taken evenly (deterministic)."""
    if len(points) <= SHEET_SAMPLE:
        return points
    out: F64 = points[np.linspace(0, len(points) - 1, SHEET_SAMPLE).astype(int)]
    return out


def _near(profs: list[F64], nominal: F64, normal: F64, reach_mm: float) -> list[F64]:
    """Each profile's points within reach_mm of the line through nominal along normal (the
    profiles as one array: a sweep's tens of profiles at once)."""
    if len({p.shape[1] for p in profs}) != 1:
        return [p[_radial(p[:, :3], nominal, normal) <= reach_mm] for p in profs]
    every = np.concatenate(profs)
    keep = _radial(every[:, :3], nominal, normal) <= reach_mm
    # the points kept before each profile's first row and after its last
    kept = np.r_[0, np.cumsum(keep)][np.r_[0, np.cumsum([len(p) for p in profs])]]
    return np.split(every[keep], kept[1:-1])


def _radial(points: F64, nominal: F64, normal: F64) -> F64:
    """Distances (n,) of points from the line through nominal along normal."""
    out: F64 = np.linalg.norm(_off_normal(points - nominal, normal), axis=1)
    return out


def _fit_circle(uv: F64) -> tuple[F64, F64, float]:
    """(a, b, r), their covariance (3, 3) and the RMS of the radial residuals: Kasa's algebraic
    fit, then geometric least squares, trimmed once at 3 sigma."""
    A = np.column_stack([2 * uv, np.ones(len(uv))])
    sol = np.linalg.lstsq(A, (uv**2).sum(axis=1), rcond=None)[0]
    x0 = np.array([sol[0], sol[1], np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1e-6))])

    def resid(p: F64, pts: F64) -> F64:
        out: F64 = np.linalg.norm(pts - p[:2], axis=1) - p[2]
        return out

    return _robust_lsq(resid, x0, uv)


def _fit_slot(uv: F64, axis_uv: F64, nominal: Sequence[float]) -> tuple[F64, F64, float]:
    """(a, b, angle, width, length) of a stadium through the edge points, its covariance (5, 5)
    and the RMS of the residuals; started on the points' centroid and the nominal axis."""
    theta0 = float(np.arctan2(axis_uv[1], axis_uv[0]))
    x0 = np.array([*uv.mean(axis=0), theta0, float(nominal[0]), float(nominal[1])])

    def resid(p: F64, pts: F64) -> F64:
        d = np.array([np.cos(p[2]), np.sin(p[2])])
        rel = pts - p[:2]
        half = max(0.5 * (p[4] - p[3]), 0.0)
        s = np.clip(rel @ d, -half, half)
        out: F64 = np.linalg.norm(rel - s[:, None] * d, axis=1) - 0.5 * p[3]
        return out

    return _robust_lsq(resid, x0, uv)


def _robust_lsq(resid, x0: F64, pts: F64) -> tuple[F64, F64, float]:  # type: ignore[no-untyped-def]
    from scipy.optimize import least_squares  # here: about half a second to import

    keep = np.ones(len(pts), dtype=bool)
    for _ in range(2):
        fit = least_squares(resid, x0, args=(pts[keep],), method="lm", xtol=1e-12, ftol=1e-12)
        r = resid(fit.x, pts)
        sigma = float(np.sqrt(np.mean(r[keep] ** 2)))
        new = np.abs(r) <= max(3.0 * sigma, 1e-6)
        x0 = fit.x
        if np.array_equal(new, keep) or new.sum() <= len(x0) + 2:
            break
        keep = new
    r = resid(x0, pts[keep])
    dof = max(int(keep.sum()) - len(x0), 1)
    s2 = float(r @ r) / dof
    J = fit.jac
    try:
        cov = np.linalg.inv(J.T @ J) * s2
    except np.linalg.LinAlgError as exc:
        raise FeatureRefused("fit", "the edge points do not determine the primitive") from exc
    return x0, cov, float(np.sqrt(np.mean(r**2)))


def _coverage(rel_uv: F64) -> float:
    """Share of COVERAGE_BINS angle bins about the centre holding at least one point."""
    ang = np.arctan2(rel_uv[:, 1], rel_uv[:, 0])
    bins = np.floor((ang + np.pi) / (2 * np.pi) * COVERAGE_BINS).astype(int) % COVERAGE_BINS
    return len(np.unique(bins)) / COVERAGE_BINS


def _lift(plane: Plane, cov_uv: F64) -> F64:
    """The in-plane covariance (2, 2) as a 3-D one, plus the plane's own offset variance."""
    e1, e2 = plane.basis()
    E = np.column_stack([e1, e2])
    out: F64 = E @ cov_uv @ E.T + plane.rms_mm**2 / plane.n_inliers * np.outer(
        plane.normal, plane.normal
    )
    return out


def _off_normal(d: F64, normal: F64) -> F64:
    out: F64 = d - np.outer(d @ normal, normal)
    return out


def _unit(v: F64) -> F64:
    return np.asarray(v / np.linalg.norm(v))
