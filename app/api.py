"""The Python API for the inspection software: the identified calibration in use. Programs
import it as `rvis` (rvis/__init__.py: the same code under a name that cannot collide with
their own packages):

    from rvis import Calibration

    cal = Calibration.load("params.json")                 # once; checks the model
    p_part_mm = cal.to_part(q_deg, p_sensor_mm)           # sensor points -> part frame
    comp = cal.compensate_joints(q_deg)                   # joint targets for the controller
    comp = cal.compensate_poses(xyzwpr)                   # or from poses in the part frame

Units and frames as everywhere in rvis: controller joint angles in degrees (J3 from the horizon,
as the pendant shows them), lengths in mm, poses in the part frame, FANUC W/P/R in degrees
(R = Rz(r) Ry(p) Rx(w)). Everything is batched over the leading axis. docs/api.md documents
it with an example that tests/inuse/test_api.py runs.

Every argument is checked before it is used, as scipy's `check_*` helpers do: its shape, that
every value is a finite number within the bounds rvis reads from files (angles within +-720 deg,
lengths within 1e5 mm); a wrong one is a ValueError (TypeError for a wrong type) whose message
starts with the argument's name, never a NaN result or a misleading "no solution".
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.formats.files import MAX_ANGLE_DEG, MAX_COORD_MM
from app.formats.params import covariance_of, from_json
from calib import compensate, urdf
from calib.compliance import CompliantModel
from calib.model import SystemModel
from calib.transforms import apply
from calib.wpr import pose_from_xyzwpr, xyzwpr_from_pose

F64 = NDArray[np.float64]

#: The model the parameters must be of (`SystemModel.name`, `.version` as written by identify).
MODEL_NAME = "fanuc-m710ic50-mdh30"
MODEL_VERSION = 1


def load_parameters(path: str | Path) -> tuple[SystemModel, F64]:
    """(model, parameters (37,)) of a parameters JSON (app.formats.params.from_json: validated,
    refusing another model or a failed identification)."""
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path: expected a file name (str or path), got {type(path).__name__}")
    return from_json(path)


@dataclass(frozen=True)
class Calibration:
    """An identified calibration: the nominal system model and its parameters x (37,)."""

    model: SystemModel
    x: F64
    source: str = ""
    # (active parameter names, their covariance) of the identification, when known
    covariance: tuple[list[str], F64] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.model, SystemModel):
            raise TypeError(f"model: expected a SystemModel, got {type(self.model).__name__}")
        n = len(self.model.names)
        x = _numbers("x", self.x)
        if x.shape != (n,):
            raise ValueError(f"x: expected shape ({n},) for {self.model.name}, got {x.shape}")
        _finite("x", x)
        object.__setattr__(self, "x", x)

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a parameters JSON (from `rvis identify`); InputError naming the file if it is
        not one or is of another model."""
        model, x = load_parameters(path)
        return cls(model, x, str(path), covariance_of(path))

    @classmethod
    def nominal(cls, model: SystemModel) -> Calibration:
        """The uncalibrated system (what the controller believes)."""
        if not isinstance(model, SystemModel):
            raise TypeError(f"model: expected a SystemModel, got {type(model).__name__}")
        return cls(model, model.nominal_x(), "<nominal>")

    def sensor_pose(self, q_deg: ArrayLike, temp_c: float | None = None) -> F64:
        """T_part_sensor (N, 4, 4) [mm] at controller angles (N, 6) or (6,) [deg]; temp_c: the
        cell's temperature [degC], for a compliance- and temperature-aware model's thermal
        growth (None: the model's reference temperature; a rigid model has no thermal term)."""
        q = _joints("q_deg", q_deg)
        if temp_c is None or not isinstance(self.model, CompliantModel):
            return self.model.fk(self.x, q)
        if not (math.isfinite(temp_c) and -40.0 <= temp_c <= 100.0):
            raise ValueError(f"temp_c = {temp_c!r}: expected a temperature within -40..100 degC")
        return self.model.fk(self.x, q, temp_c=float(temp_c))

    def to_part(self, q_deg: ArrayLike, p_sensor_mm: ArrayLike) -> F64:
        """Sensor points in the part frame [mm]. q_deg (N, 6) with points (N, 3) (one point per
        configuration) or (N, M, 3) (a profile of M points per configuration); q_deg (6,)
        with points (M, 3) or (3,). The result has the shape of the points."""
        q = _joints("q_deg", q_deg)
        p = _numbers("p_sensor_mm", p_sensor_mm)
        single = np.ndim(q_deg) == 1
        allowed = (1, 2) if single else (2, 3)
        if p.ndim not in allowed or p.shape[-1] != 3:
            want = "(M, 3) or (3,)" if single else "(N, 3) or (N, M, 3)"
            raise ValueError(
                f"p_sensor_mm: expected shape {want} with q_deg {np.shape(q_deg)}, got {p.shape}"
            )
        if not single and p.shape[0] != q.shape[0]:
            raise ValueError(
                f"p_sensor_mm: {p.shape[0]} rows of points but q_deg has {q.shape[0]}"
                " configurations (one row per configuration)"
            )
        _finite("p_sensor_mm", p, MAX_COORD_MM, "mm")
        T = self.model.fk(self.x, q)
        if single:
            return apply(T[0], p)
        return apply(T, p) if p.ndim == 2 else apply(T[:, None], p)

    def u95_mm(
        self, q_deg: ArrayLike, p_sensor_mm: ArrayLike, statement_u95_mm: float = 0.0
    ) -> F64:
        """The task-specific U95 [mm] of each point `to_part` maps (shapes as there; the result
        has the points' shape less the last axis): the identification's covariance propagated
        to that point's pose (J cov J^T, its largest eigenvalue as the per-coordinate variance:
        never understated), combined in quadrature with `statement_u95_mm`, the U95 the cell
        states for a point measured now (`rvis status` accuracy.u95_mm: the terms the
        covariance does not see, sensor, robot repeatability, temperature), both at 95 %
        (calib.uncertainty). Without a covariance (a nominal calibration) only the statement."""
        from calib.uncertainty import norm_quantile

        q = _joints("q_deg", q_deg)
        p = _numbers("p_sensor_mm", p_sensor_mm)
        self.to_part(q_deg, p_sensor_mm)  # the same checks of the shapes and values
        if not (np.isfinite(statement_u95_mm) and statement_u95_mm >= 0):
            raise ValueError(f"statement_u95_mm: expected a number >= 0, got {statement_u95_mm}")
        shape = p.shape[:-1]
        pts = p.reshape(-1, 3)
        qs = np.repeat(q.reshape(-1, 6), len(pts) // len(q.reshape(-1, 6)), axis=0)
        k = norm_quantile()
        var: F64 = np.zeros(len(pts))
        if self.covariance is not None:
            names, cov = self.covariance
            J = self.model.point_jacobian(self.x, qs, pts, names)  # (n, 3, k)
            var = np.asarray(np.linalg.eigvalsh(J @ cov @ np.swapaxes(J, 1, 2))[:, -1], float)
        out: F64 = k * np.sqrt(np.clip(var, 0.0, None) + (statement_u95_mm / k) ** 2)
        return out.reshape(shape)

    def compensate_joints(
        self, q_deg: ArrayLike, settings: compensate.CompensationSettings | None = None
    ) -> compensate.Compensation:
        """Compensated joints (N, 6) for joint targets (N, 6) [deg] taught or planned on the
        nominal model; rows that cannot be compensated have ok False and a reason."""
        q = _joints("q_deg", q_deg)
        return compensate.compensate_joints(self.model, self.x, q, _settings(settings))

    def compensate_poses(
        self,
        xyzwpr: ArrayLike,
        q_hint_deg: ArrayLike | None = None,
        settings: compensate.CompensationSettings | None = None,
    ) -> compensate.Compensation:
        """Compensated joints for intended sensor poses (N, 6) x, y, z [mm], w, p, r [deg] in
        the part frame; q_hint_deg (N, 6): joints whose branch to keep (NaN rows: none)."""
        poses = _rows("xyzwpr", xyzwpr)
        _finite("xyzwpr", poses, np.array([MAX_COORD_MM] * 3 + [MAX_ANGLE_DEG] * 3), "mm or deg")
        hints = None if q_hint_deg is None else _hints(q_hint_deg, poses.shape[0])
        T = pose_from_xyzwpr(poses)
        return compensate.compensate_poses(self.model, self.x, T, hints, _settings(settings))

    def urdf(self) -> str:
        """The URDF of this calibration (see calib/urdf.py)."""
        return urdf.urdf_xml(self.model, self.x)


def command_xyzwpr(result: compensate.Compensation) -> F64:
    """The compensated Cartesian targets (N, 6) x, y, z [mm], w, p, r [deg] (part frame) for a
    controller running its nominal model; NaN rows where not ok."""
    if not isinstance(result, compensate.Compensation):
        raise TypeError(f"result: expected a Compensation, got {type(result).__name__}")
    out = np.full((result.T_command.shape[0], 6), np.nan)
    out[result.ok] = xyzwpr_from_pose(result.T_command[result.ok])
    return out


# -- argument checks (each names the argument) ---------------------------------------------------
def _joints(name: str, value: ArrayLike) -> F64:
    """Controller angles (N, 6) [deg] from (N, 6) or (6,): finite, within +-MAX_ANGLE_DEG."""
    q = _rows(name, value)
    _finite(name, q, MAX_ANGLE_DEG, "deg")
    return q


def _numbers(name: str, value: ArrayLike) -> F64:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from exc
    return a


def _rows(name: str, value: ArrayLike) -> F64:
    """Rows of 6 values (N, 6) from (N, 6) or (6,); at least one row."""
    a = _numbers(name, value)
    if a.ndim not in (1, 2) or a.shape[-1] != 6 or a.size == 0:
        raise ValueError(f"{name}: expected shape (N, 6) or (6,) with N >= 1, got {a.shape}")
    return a.reshape(-1, 6)


def _finite(name: str, a: F64, limit: ArrayLike | None = None, unit: str = "") -> None:
    """Every value finite (and within +-limit, broadcast over the last axis)."""
    bad = ~np.isfinite(a)
    if limit is not None:
        bad |= np.abs(np.nan_to_num(a)) > limit
    if np.any(bad):
        at = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"{name}[{', '.join(map(str, at))}]" if at else name
        bound = "" if limit is None else f" within +-{np.max(limit):g} {unit}"
        raise ValueError(f"{where} = {float(a[at])!r}: expected a finite number{bound}")


def _hints(value: ArrayLike, n: int) -> F64:
    """q_hint_deg: one row per pose (N, 6), each all finite or all NaN (no hint)."""
    hints = _rows("q_hint_deg", value)
    if hints.shape[0] != n:
        raise ValueError(
            f"q_hint_deg: {hints.shape[0]} rows but xyzwpr has {n} poses (one hint row per pose;"
            " a NaN row: none)"
        )
    given = ~np.all(np.isnan(hints), axis=1)
    partial = np.flatnonzero(given & np.any(np.isnan(hints), axis=1))
    if partial.size:
        raise ValueError(
            f"q_hint_deg[{partial[0]}] = {hints[partial[0]].tolist()}: a hint row is six"
            " angles or all NaN (no hint)"
        )
    _finite("q_hint_deg", np.where(given[:, None], hints, 0.0), MAX_ANGLE_DEG, "deg")
    return hints


def _settings(
    settings: compensate.CompensationSettings | None,
) -> compensate.CompensationSettings | None:
    if settings is not None and not isinstance(settings, compensate.CompensationSettings):
        raise TypeError(f"settings: expected a CompensationSettings, got {type(settings).__name__}")
    return settings
