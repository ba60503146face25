"""What the simulated line knows and the service must find out: the truth over sim time.

`LineTruth` is the app's window on the cell's truth (for reports and tests, never for the
service's decisions): the true sensor pose at any sim time, and 100 fixed validation positions.
fakes/ imports no calib/, so the true *validation error* of some parameters is computed by the
app: for each position, the model's part-frame point of the true sensor-frame centre
(`validation_centres_sensor_mm(t)`, seen from where the robot stands after its move there: its
repeatability included) minus the true position (`validation.p_part_mm`).

The validation positions are drawn without any inverse kinematics: a seeded random configuration
in the robot's working range, and a point inside the sensor's measuring volume seen from it at
sim time 0, kept if it lies in the workspace band of the spheres (900-1900 mm from the J1 axis,
-300..700 mm high in the base frame, as app.sim.cell's validation points).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fakes.cell import SimulatedCell

F64 = NDArray[np.float64]

#: Controller-angle ranges [deg] the validation configurations are drawn from (J2, J3 kept to
#: the arm's usual working range, J5 away from the wrist singularity).
_Q_LOW_DEG = np.array([-180.0, -30.0, -40.0, -180.0, -120.0, -180.0])
_Q_HIGH_DEG = np.array([180.0, 60.0, 40.0, 180.0, 120.0, 180.0])
_RADIUS_MM = (900.0, 1900.0)
_HEIGHT_MM = (-300.0, 700.0)


@dataclass(frozen=True)
class ValidationPositions:
    """Validation positions: q_deg (n, 6) controller angles, p_part_mm (n, 3) true points in
    the part frame, seen from q_deg inside the measuring volume (at sim time 0)."""

    q_deg: F64
    p_part_mm: F64

    def __len__(self) -> int:
        return int(self.q_deg.shape[0])


def validation_positions(
    cell: SimulatedCell, n: int, rng: np.random.Generator
) -> ValidationPositions:
    """n seeded validation positions of the cell (see the module docstring)."""
    vol = cell.spec.volume
    T_base_part = np.linalg.inv(cell.spec.T_part_base)
    qs: list[F64] = []
    ps: list[F64] = []
    while len(qs) < n:
        q = rng.uniform(_Q_LOW_DEG, _Q_HIGH_DEG, (4 * n, 6))
        c = np.column_stack(
            [
                rng.uniform(-0.8, 0.8, 4 * n) * vol.half_x_mm,
                rng.uniform(-0.8, 0.8, 4 * n) * vol.half_y_mm,
                rng.uniform(vol.z_min_mm, vol.z_max_mm, 4 * n),
            ]
        )
        T = cell.T_part_sensor(q, 0.0)
        p = np.einsum("nij,nj->ni", T[:, :3, :3], c) + T[:, :3, 3]
        p_base = p @ T_base_part[:3, :3].T + T_base_part[:3, 3]
        r = np.hypot(p_base[:, 0], p_base[:, 1])
        keep = (r >= _RADIUS_MM[0]) & (r <= _RADIUS_MM[1])
        keep &= (p_base[:, 2] >= _HEIGHT_MM[0]) & (p_base[:, 2] <= _HEIGHT_MM[1])
        qs.extend(q[keep])
        ps.extend(p[keep])
    return ValidationPositions(np.array(qs[:n]), np.array(ps[:n]))


class LineTruth:
    """The cell's truth at any sim time (default: now on the line's clock)."""

    def __init__(self, cell: SimulatedCell, validation: ValidationPositions) -> None:
        self.cell = cell
        self.validation = validation

    def now_s(self) -> float:
        return self.cell.now_s()

    def temp_c(self, t_s: float | None = None) -> float:
        """The cell temperature [deg C]."""
        return self.cell.temp_at(t_s)

    def T_tool0_sensor(self, t_s: float | None = None) -> F64:
        """The true sensor mount (4, 4) on the flange."""
        return self.cell.mount_at(t_s)

    def T_part_sensor(self, q_deg: ArrayLike, t_s: float | None = None) -> F64:
        """True forward kinematics: sensor poses (N, 4, 4) in the part frame for controller
        angles (N, 6) [deg], with the compliance, the temperature and the mount at t_s."""
        return self.cell.T_part_sensor(q_deg, t_s)

    def joints_deg(self) -> F64:
        """Where the true robot is now (controller angles [deg])."""
        return self.cell.joints_deg()

    def sphere_part_mm(self, target_id: str) -> F64:
        """A sphere's true centre (3,) in the part frame."""
        return self.cell.target_true_mm(target_id)

    def validation_centres_sensor_mm(self, t_s: float | None = None) -> F64:
        """True centres (n, 3) in the sensor frame of the validation positions at t_s: what a
        perfect sensor would measure from each position's configuration, each a move of the
        robot there (`SimulatedCell.centres_from_stops`: the robot's repeatability is part of
        a validation measurement's error; the same t_s, the same stops)."""
        v = self.validation
        return self.cell.centres_from_stops(v.q_deg, v.p_part_mm, t_s)
