"""The Python API for the inspection software: the identified calibration in use.

    from app.api import Calibration

    cal = Calibration.load("params.json")                 # once; checks the model
    p_part_mm = cal.to_part(q_deg, p_sensor_mm)           # sensor points -> part frame
    comp = cal.compensate_joints(q_deg)                   # joint targets for the controller
    comp = cal.compensate_poses(xyzwpr)                   # or from poses in the part frame

Units and frames as everywhere in rvis: controller joint angles in degrees (J3 from the horizon,
as the pendant shows them), lengths in mm, poses in the part frame, FANUC W/P/R in degrees
(R = Rz(r) Ry(p) Rx(w)). Everything is batched over the leading axis. docs/api.md documents
it with an example that tests/inuse/test_api.py runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.params import from_json
from calib import compensate, urdf
from calib.model import SystemModel
from calib.transforms import apply
from calib.wpr import pose_from_xyzwpr, xyzwpr_from_pose

F64 = NDArray[np.float64]

#: The model the parameters must be of (`SystemModel.name`, `.version` as written by identify).
MODEL_NAME = "fanuc-m710ic50-mdh30"
MODEL_VERSION = 1


def load_parameters(path: str | Path) -> tuple[SystemModel, F64]:
    """(model, parameters (37,)) of a parameters JSON (app.params.from_json: validated,
    refusing another model or a failed identification)."""
    return from_json(path)


@dataclass(frozen=True)
class Calibration:
    """An identified calibration: the nominal system model and its parameters x (37,)."""

    model: SystemModel
    x: F64
    source: str = ""

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a parameters JSON (from `rvis identify`); InputError naming the file if it is
        not one or is of another model."""
        model, x = load_parameters(path)
        return cls(model, x, str(path))

    @classmethod
    def nominal(cls, model: SystemModel) -> Calibration:
        """The uncalibrated system (what the controller believes)."""
        return cls(model, model.nominal_x(), "<nominal>")

    def sensor_pose(self, q_deg: ArrayLike) -> F64:
        """T_part_sensor (N, 4, 4) [mm] at controller angles (N, 6) or (6,) [deg]."""
        return self.model.fk(self.x, q_deg)

    def to_part(self, q_deg: ArrayLike, p_sensor_mm: ArrayLike) -> F64:
        """Sensor points in the part frame [mm]. q_deg (N, 6) with points (N, 3) (one point per
        configuration) or (N, M, 3) (a profile of M points per configuration); q_deg (6,)
        with points (M, 3). The result has the shape of the points."""
        q = np.asarray(q_deg, dtype=float)
        p = np.asarray(p_sensor_mm, dtype=float)
        if q.shape[-1:] != (6,) or p.shape[-1:] != (3,):
            raise ValueError(
                f"expected joints (..., 6) and points (..., 3), got {q.shape}, {p.shape}"
            )
        T = self.sensor_pose(q.reshape(-1, 6))
        if q.ndim == 1:
            return apply(T[0], p)
        if p.ndim == 2:
            if p.shape[0] != T.shape[0]:
                raise ValueError(f"{T.shape[0]} configurations but {p.shape[0]} points")
            return apply(T, p)
        if p.ndim != 3 or p.shape[0] != T.shape[0]:
            raise ValueError(f"points {p.shape} do not match {T.shape[0]} configurations")
        return apply(T[:, None], p)

    def compensate_joints(
        self, q_deg: ArrayLike, settings: compensate.CompensationSettings | None = None
    ) -> compensate.Compensation:
        """Compensated joints (N, 6) for joint targets (N, 6) [deg] taught or planned on the
        nominal model; rows that cannot be compensated have ok False and a reason."""
        return compensate.compensate_joints(self.model, self.x, q_deg, settings)

    def compensate_poses(
        self,
        xyzwpr: ArrayLike,
        q_hint_deg: ArrayLike | None = None,
        settings: compensate.CompensationSettings | None = None,
    ) -> compensate.Compensation:
        """Compensated joints for intended sensor poses (N, 6) x, y, z [mm], w, p, r [deg] in
        the part frame; q_hint_deg (N, 6): joints whose branch to keep (NaN rows: none)."""
        T = pose_from_xyzwpr(xyzwpr)
        return compensate.compensate_poses(self.model, self.x, T, q_hint_deg, settings)

    def urdf(self) -> str:
        """The URDF of this calibration (see calib/urdf.py)."""
        return urdf.urdf_xml(self.model, self.x)


def command_xyzwpr(result: compensate.Compensation) -> F64:
    """The compensated Cartesian targets (N, 6) x, y, z [mm], w, p, r [deg] (part frame) for a
    controller running its nominal model; NaN rows where not ok."""
    out = np.full((result.T_command.shape[0], 6), np.nan)
    out[result.ok] = xyzwpr_from_pose(result.T_command[result.ok])
    return out
