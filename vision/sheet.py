"""The sheet around a body feature: its plane from the stripe points, and the edge points where
a stripe breaks at a hole or slot.

A galvo sweep over a feature gives one profile per frame: the 3-D points of one laser stripe,
ordered along the stripe (the camera rows), in any one frame (the caller's; the part frame
when the robot's pose is applied). On the sheet they lie on its top face; at a hole the stripe
breaks (the light goes through, or lands on the bore's far wall, below the top face).

Edge points: where a run of points on the top face ends inside the profile (a gap, or points
that leave the plane), the edge lies between the last point on the face and where the next one
would have been: the last point plus half a sample step along the stripe (a stripe sampled every
step s finds an edge, on average, s/2 before it). That is the sub-pixel location on the sheet's
top edge, what a CMM probes; the points on the bore's wall never become edge points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vision.errors import FeatureRefused

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class SheetSettings:
    """How the sheet and its edges are found [mm].

    plane_tol_mm: a point is on the top face within this of the plane (the bore's wall points
    and anything behind the sheet are further); max_plane_rms_mm: a plane whose inliers scatter
    more does not fit (a bent or curled sheet, a wrong view); min_plane_points: fewer inliers
    refuse the plane; a break in a profile is a gap of more than gap_steps median steps and
    more than min_gap_mm (the sensor's noise moves neighbours apart by a few steps)."""

    plane_tol_mm: float = 0.15
    max_plane_rms_mm: float = 0.05
    min_plane_points: int = 200
    gap_steps: float = 3.0
    min_gap_mm: float = 0.3


@dataclass(frozen=True)
class Plane:
    """A plane: point_mm (3,) on it, unit normal (3,) oriented like the hint; rms_mm of its
    inliers' distances; n_inliers."""

    point_mm: F64
    normal: F64
    rms_mm: float
    n_inliers: int

    def distance_mm(self, points_mm: F64) -> F64:
        """Signed distances (n,) of points (n, 3) along the normal."""
        out: F64 = (points_mm - self.point_mm) @ self.normal
        return out

    def basis(self) -> tuple[F64, F64]:
        """Two unit vectors (3,) spanning the plane, right-handed with the normal."""
        n = self.normal
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(n, ref)
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1)

    def to_2d(self, points_mm: F64, origin_mm: F64) -> F64:
        """Points (n, 3) projected onto the plane, as coordinates (n, 2) about origin_mm."""
        e1, e2 = self.basis()
        d = points_mm - origin_mm
        return np.column_stack([d @ e1, d @ e2])

    def from_2d(self, uv_mm: F64, origin_mm: F64) -> F64:
        """Plane coordinates (n, 2) about origin_mm (projected onto the plane) back to 3-D."""
        e1, e2 = self.basis()
        o = origin_mm - self.distance_mm(origin_mm[None])[0] * self.normal
        out: F64 = o + uv_mm[:, :1] * e1 + uv_mm[:, 1:2] * e2
        return out


def fit_plane(
    points_mm: F64, normal_hint: F64, settings: SheetSettings | None = None, iterations: int = 3
) -> Plane:
    """The least-squares plane of points (n, 3) on a sheet, trimmed to the points within
    plane_tol_mm of it (a few passes: the bore's wall and the background leave); the normal
    oriented along normal_hint. FeatureRefused("plane") when too few points are on it or they
    scatter more than max_plane_rms_mm."""
    s = settings or SheetSettings()
    keep = np.ones(len(points_mm), dtype=bool)
    plane = None
    for _ in range(iterations):
        if keep.sum() < max(3, s.min_plane_points):
            break
        plane = _lsq_plane(points_mm[keep], normal_hint)
        keep = np.abs(plane.distance_mm(points_mm)) <= s.plane_tol_mm
    if plane is None or keep.sum() < s.min_plane_points:
        raise FeatureRefused(
            "plane", f"{int(keep.sum())} points on the sheet, at least {s.min_plane_points}"
        )
    plane = _lsq_plane(points_mm[keep], normal_hint)
    if plane.rms_mm > s.max_plane_rms_mm:
        raise FeatureRefused(
            "plane",
            f"the sheet's points scatter {plane.rms_mm:.3f} mm about their plane"
            f" (at most {s.max_plane_rms_mm:g} mm)",
        )
    return plane


def _lsq_plane(points_mm: F64, normal_hint: F64) -> Plane:
    c = points_mm.mean(axis=0)
    _, _, vt = np.linalg.svd(points_mm - c, full_matrices=False)
    n = vt[2] if vt[2] @ normal_hint >= 0 else -vt[2]
    d = (points_mm - c) @ n
    return Plane(c, n, float(np.sqrt(np.mean(d**2))), len(points_mm))


def edge_points(
    profiles: Sequence[F64], plane: Plane, settings: SheetSettings | None = None
) -> F64:
    """The edge points (m, 3) on the sheet's top face where the stripes break (module
    docstring): each profile's runs of points on the face, their ends inside the profile
    (never the profile's own ends: the field of view's border is no edge), each moved half a
    step on along the stripe, away from its run."""
    s = settings or SheetSettings()
    out: list[F64] = []
    for prof in profiles:
        on = np.abs(plane.distance_mm(prof)) <= s.plane_tol_mm
        idx = np.flatnonzero(on)
        if len(idx) < 4:
            continue
        # the step in the sheet's plane: the noise along the camera's ray (mostly along the
        # normal) would lengthen it, and the half step would then overshoot the edge
        diffs = np.diff(prof[idx], axis=0)
        steps = np.linalg.norm(diffs - np.outer(diffs @ plane.normal, plane.normal), axis=1)
        step = float(np.median(steps))
        along = prof[idx[-1]] - prof[idx[0]]
        along -= (along @ plane.normal) * plane.normal
        along /= np.linalg.norm(along)
        # a run ends where the next point on the face is not the next sample or is far away
        gap = max(s.gap_steps * step, s.min_gap_mm)
        for b in np.flatnonzero((np.diff(idx) > 1) | (steps > gap)):
            out.append(prof[idx[b]] + 0.5 * step * along)
            out.append(prof[idx[b + 1]] - 0.5 * step * along)
    return np.array(out).reshape(-1, 3)
