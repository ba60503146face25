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

A profile measured from images (vision.triangulate.triangulate_profiles: each point with the
stripe's width along its image row and its row's flux) says more, and needs it. Where the edge
crosses the stripe at a slant, the rows near it are cut across the stripe's width: a cut row's
centroid moves to its lit side, its point leaves the face along its image row (by up to the
plane tolerance; in the plane 10-30 um off the stripe's line), and rows whose centre is already
in the opening still pass as the face's; the optics' blur lends the first row past an edge a
dim, centred copy of the last one; the bore's wall, where it is lit and seen, continues the
stripe below the face. A row is the face's while its centre is, that is while at least half of
its light is there: its flux at least HALF_LIGHT of the face's median row (the speckle's median,
not its mean: a row at half the light is then as likely above as below), and its point no
further off the face than a cut through the stripe's centre moves it (HALF_CUT_SHIFT widths) by
more than SCATTER_K times the points' own scatter (further is the wall). Of a run's END_WINDOW
rows from its end inwards, the outermost such row, moved in by one row for each row inside it
that is not (so that a row the speckle dims and one it brightens past the edge cancel); that
row's point moved along its image row back onto the face (where the stripe's centre is in that
row), plus half a step, is the edge point. Profiles of points alone keep the rule above.
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
    plane, settled = None, False
    for _ in range(iterations):
        if keep.sum() < max(3, s.min_plane_points):
            break
        plane = _lsq_plane(points_mm[keep], normal_hint)
        kept, keep = keep, np.abs(plane.distance_mm(points_mm)) <= s.plane_tol_mm
        if np.array_equal(keep, kept):  # the same points again: so would every pass be
            settled = True
            break
    if plane is None or keep.sum() < s.min_plane_points:
        raise FeatureRefused(
            "plane", f"{int(keep.sum())} points on the sheet, at least {s.min_plane_points}"
        )
    if not settled:
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
    centred = points_mm - c
    # the normal: the scatter matrix's eigenvector of the least eigenvalue (the last right
    # singular vector of the centred points, at a third of an SVD's cost on many points)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    n = vecs[:, 0] if vecs[:, 0] @ normal_hint >= 0 else -vecs[:, 0]
    d = centred @ n
    return Plane(c, n, float(np.sqrt(np.mean(d**2))), len(points_mm))


#: a row is the face's while its flux is at least this share of the face's median row's
HALF_LIGHT = 0.5
#: how many of a run's points, from its end inwards, the half-light rule reads
END_WINDOW = 16
#: how far (in the stripe's widths) an edge through a Gaussian stripe's centre moves its
#: centroid: sqrt(2 / pi); a row cut less moves less
HALF_CUT_SHIFT = float(np.sqrt(2.0 / np.pi))
#: beyond that, plus this many times the points' own scatter off the face, a row is not the
#: face's whatever its light (the bore's wall below it)
SCATTER_K = 2.0
#: the columns of a profile with its light (vision.triangulate.PROFILE_COLUMNS)
LIT_COLUMNS = 7


def edge_points(
    profiles: Sequence[F64], plane: Plane, settings: SheetSettings | None = None
) -> F64:
    """The edge points (m, 3) on the sheet's top face where the stripes break (module
    docstring): each profile's runs of points on the face, their ends inside the profile
    (never the profile's own ends: the field of view's border is no edge), each moved half a
    step on along the stripe, away from its run. Profiles (n_i, 3) of points, or (n_i, 7) of
    points with their light (vision.triangulate.triangulate_profiles): the end is then the
    outermost row that is still the face's (module docstring)."""
    s = settings or SheetSettings()
    profs = list(profiles)
    if not profs:
        return np.zeros((0, 3))
    # every profile at once: its points on the face (idx, global rows), the steps between
    # neighbours on the face within a profile (pairs j: idx[j] -> idx[j + 1]), its median step
    lens = np.array([len(p) for p in profs])
    points = np.concatenate([p[:, :3] for p in profs])
    owner = np.repeat(np.arange(len(profs)), lens)
    idx = np.flatnonzero(np.abs(plane.distance_mm(points)) <= s.plane_tol_mm)
    used = np.bincount(owner[idx], minlength=len(profs)) >= 4
    idx = idx[used[owner[idx]]]
    pid = owner[idx]
    j = np.flatnonzero(pid[1:] == pid[:-1])
    steps = _in_plane(points[idx[j + 1]] - points[idx[j]], plane)
    step = _medians(steps, pid[j], len(profs))
    # the step in the sheet's plane: the noise along the camera's ray (mostly along the
    # normal) would lengthen it, and the half step would then overshoot the edge
    first = np.searchsorted(pid, np.arange(len(profs)))
    last = np.searchsorted(pid, np.arange(len(profs)), side="right") - 1
    along = np.zeros((len(profs), 3))
    for k in np.flatnonzero(used).tolist():  # one by one: the same unit vectors to the bit
        a = points[idx[last[k]]] - points[idx[first[k]]]
        a -= (a @ plane.normal) * plane.normal
        along[k] = a / np.linalg.norm(a)
    # a run ends where the next point on the face is not the next sample or is far away
    gap = np.maximum(s.gap_steps * step, s.min_gap_mm)
    b = j[(idx[j + 1] - idx[j] > 1) | (steps > gap[pid[j]])]
    if any(p.shape[1] >= LIT_COLUMNS for p in profs):
        out: list[F64] = []
        starts = np.r_[0, np.cumsum(lens)]
        for k in np.unique(pid[b]):
            mine = idx[first[k] : last[k] + 1]
            local = b[pid[b] == k] - first[k]  # indices into mine
            out.extend(_lit_ends(profs[k], mine - starts[k], local, plane, along[k]))
        return np.array(out).reshape(-1, 3)
    half = (0.5 * step[pid[b]])[:, None] * along[pid[b]]
    ends = np.stack([points[idx[b]] + half, points[idx[b + 1]] - half], axis=1)
    out_mm: F64 = ends.reshape(-1, 3)
    return out_mm


def _medians(values: F64, group: NDArray[np.intp], n: int) -> F64:
    """Each group's median of values (n,) (np.median's: the mean of the two middle values
    of an even count); NaN for a group with none. `group` (m,) ascending."""
    count = np.bincount(group, minlength=n)
    start = np.r_[0, np.cumsum(count)[:-1]]
    rows = np.full((n, max(int(count.max(initial=0)), 1)), np.inf)
    rows[group, np.arange(len(values)) - start[group]] = values
    rows.sort(axis=1)
    k = np.arange(n)
    pick = np.c_[rows[k, np.maximum(count - 1, 0) // 2], rows[k, count // 2]]
    out: F64 = np.where(count > 0, (pick[:, 0] + pick[:, 1]) / 2.0, np.nan)
    return out


def _in_plane(d: F64, plane: Plane) -> F64:
    """Lengths (n,) of vectors d (n, 3) projected onto the plane."""
    out: F64 = np.linalg.norm(d - np.outer(d @ plane.normal, plane.normal), axis=1)
    return out


def _lit_ends(
    prof: F64, idx: NDArray[np.intp], breaks: NDArray[np.intp], plane: Plane, along: F64
) -> list[F64]:
    """The edge points of a profile with its light (module docstring) at the ends of its runs
    of points on the face idx (indices into prof) that `breaks` (indices into idx) end."""
    points, width_mm, flux = prof[:, :3], prof[:, 3:6], prof[:, 6]
    off = plane.distance_mm(points)
    # each point moved along its image row onto the face: where the stripe's centre is in
    # its row (a row parallel to the face is left as it is)
    climb = width_mm @ plane.normal
    flat = np.abs(climb) < 1e-9
    face = points - np.where(flat, 0.0, off / np.where(flat, 1.0, climb))[:, None] * width_mm
    step = float(np.median(_in_plane(np.diff(face[idx], axis=0), plane)))
    # the face's: at least half the light of its median row, and no further off the face than
    # a cut through the stripe's centre moves it, plus the points' scatter
    scatter = 1.4826 * float(np.median(np.abs(off[idx])))
    reach = HALF_CUT_SHIFT * float(np.median(np.abs(climb[idx]))) + SCATTER_K * scatter
    lit = (flux >= HALF_LIGHT * float(np.median(flux[idx]))) & (np.abs(off) <= reach)
    ends = np.r_[breaks, len(idx) - 1]
    out: list[F64] = []
    for j, b in enumerate(breaks):
        first = 0 if j == 0 else int(breaks[j - 1]) + 1
        # the run that ends at b (outwards: +along) and the one that starts at b + 1 (-along),
        # each from its end inwards
        ending = np.arange(b, max(first, b - END_WINDOW + 1) - 1, -1)
        starting = np.arange(b + 1, min(int(ends[j + 1]), b + END_WINDOW) + 1)
        for rows, outwards in ((idx[ending], along), (idx[starting], -along)):
            the_face_s = lit[rows]
            if not the_face_s.any():
                continue
            k = int(np.argmax(the_face_s))  # the outermost
            not_inside = int(np.count_nonzero(~the_face_s[k:]))
            out.append(face[rows[k]] + (0.5 - not_inside) * step * outwards)
    return out
