"""A jump's correction as the service records it (app.line.jumps), and the points of the
measuring volume at which its uncertainty is predicted.

A correction is a calibration like a recalibration's (an app.line.recalib.RecalOutcome): it is
gated, stored (pending or rejected) and applied as a version of kind "step" (its document's
`estimator.kind`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.formats.params import plain_document, set_covariance
from app.line.recalib import RecalOutcome
from calib.cellstate import CellState
from calib.gate_limits import Gates
from calib.gates import change_failures
from calib.hypotheses import JumpFit
from calib.model import INDEX, SystemModel

F64 = NDArray[np.float64]
#: the calibration document's estimator kind of a jump's correction (app.line.versions)
KIND = "step"


def volume_points_mm(volume_mm: Sequence[float]) -> F64:
    """Points (7, 3) [mm, sensor frame] that span the measuring volume (standoff, half field of
    view x and y, half depth): its centre, the four corners of the field of view at 0.8 of its
    half widths, and the centre at the near and far depth."""
    s, hx, hy, hd = (float(v) for v in volume_mm)
    corners = [[sx * 0.8 * hx, sy * 0.8 * hy, s] for sx in (-1, 1) for sy in (-1, 1)]
    return np.array([[0.0, 0.0, s], *corners, [0.0, 0.0, s - hd], [0.0, 0.0, s + hd]])


def volume_views(q_deg: F64, volume_mm: Sequence[float]) -> tuple[F64, F64]:
    """Every configuration (K, 6) with every point of the measuring volume: (K*7, 6), (K*7, 3)
    (where a correction's uncertainty is predicted: a sensor's tilt that the spheres near the
    middle of the field of view do not show moves the points at its edges)."""
    pts = volume_points_mm(volume_mm)
    q = np.asarray(q_deg, dtype=float).reshape(-1, 6)
    return np.repeat(q, len(pts), axis=0), np.tile(pts, (len(q), 1))


def jump_correction(
    model: SystemModel,
    state: CellState,
    fit: JumpFit,
    n_after: int,
    gates: Gates,
    current: Mapping[str, Any] | None,
    covariance: tuple[list[str], F64] | None,
    version: int,
) -> RecalOutcome:
    """The parameters the estimator is referenced to (`state.x_ref`) with the jump's group moved
    by `fit`'s estimate, gated by the in-line change bounds; its document carries the version in
    force's covariance (`covariance`: names, matrix) with the jump's own added, and the version's
    workspace validation (`current`'s: the same calibration with one group moved)."""
    h = fit.hypothesis
    x_new = state.x_ref.copy()
    x_new[[INDEX[p] for p in h.params]] += fit.theta
    failures = change_failures(h.params, x_new, state.x_ref, gates)
    doc = plain_document(model, x_new, f"rvis run (jump correction: {h.label})")
    if covariance is not None:
        names, C = covariance
        cols = [names.index(p) for p in h.params if p in names]
        C = C.copy()
        C[np.ix_(cols, cols)] += fit.cov[: len(cols), : len(cols)]
        set_covariance(doc, names, C)
    validation = (current or {}).get("validation")
    if validation:
        doc["validation"] = {**validation, "inherited_from_version": version}
    doc["estimator"] = {
        "kind": KIND,
        "group": h.name,
        "onset_id": fit.onset_ref,
        "jump": [float(t) for t in fit.theta],
        "jump_std": [float(s) for s in fit.std],
        "llr": fit.llr,
    }
    doc["success"] = not failures
    rows = state.rows[fit.onset :]
    before = [float(np.linalg.norm(r.v0)) for r in rows]
    after = [float(np.linalg.norm(r.v0 - r.G[h.name] @ fit.theta)) for r in rows]
    return RecalOutcome(
        not failures,
        tuple(failures),
        x_new,
        doc,
        float(np.sqrt(np.mean(np.square(after)))) if after else math.nan,
        after[-1] if after else math.nan,
        before[-1] if before else math.nan,
        n_after,
        fit.onset_ref,
        rows[-1].obs.ref if rows else fit.onset_ref,
    )
