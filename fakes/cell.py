"""The simulated cell: the true robot, part frame, sensor mount, spheres, tracker and sensor.

It knows the truth and is seeded. Its kinematics are `fakes.truth` (URDF chain), never calib's
model. Sphere measurements here are geometric (true centre in the sensor frame plus noise);
the rendered-image path goes through `fakes.render` and vision/.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fakes.truth import TrueRobot, _rot, homogeneous

F64 = NDArray[np.float64]

#: The paper's sphere positions in the robot base frame [mm] (Table 1: pre-calibration).
PAPER_TABLE1_BASE_MM: dict[str, tuple[float, float, float]] = {
    "P1": (-647.14, 1254.27, -289.37),
    "P2": (1742.87, 1138.35, -260.87),
    "P3": (1428.57, -1347.92, 102.31),
    "P4": (-704.45, -1265.87, 680.54),
}
#: The paper's optimised positions (Table 2) [mm], robot base frame.
PAPER_TABLE2_BASE_MM: dict[str, tuple[float, float, float]] = {
    "P1": (1072.73, 1394.23, -288.43),
    "P2": (-823.53, 806.94, -261.44),
    "P3": (-1207.93, -1377.56, 101.86),
    "P4": (946.27, -1043.51, 682.61),
}


class NotVisible(Exception):
    """The sphere is outside the sensor's measuring volume from this configuration."""


@dataclass(frozen=True)
class MeasuringVolume:
    """Where a sphere centre must lie in the sensor frame to be measured [mm]: laterally
    inside the field of view, in depth within the depth of field around the ideal standoff."""

    half_x_mm: float = 18.5
    half_y_mm: float = 13.5
    z_min_mm: float = 125.0
    z_max_mm: float = 135.0

    def contains(self, c_sensor_mm: F64) -> NDArray[np.bool_]:
        c = np.atleast_2d(c_sensor_mm)
        inside: NDArray[np.bool_] = (
            (np.abs(c[:, 0]) <= self.half_x_mm)
            & (np.abs(c[:, 1]) <= self.half_y_mm)
            & (c[:, 2] >= self.z_min_mm)
            & (c[:, 2] <= self.z_max_mm)
        )
        return inside


@dataclass(frozen=True)
class CellSpec:
    """The nominal cell as designed: what the engineer believes (plain numbers, no model)."""

    T_part_base: F64
    T_flange_sensor: F64
    spheres_part_mm: Mapping[str, F64]
    sphere_radius_mm: float = 15.0
    volume: MeasuringVolume = field(default_factory=MeasuringVolume)


@dataclass(frozen=True)
class SimSettings:
    """Seeded error and noise settings of the simulated cell."""

    seed: int = 0
    tracker_noise_mm: float = 0.01
    sensor_noise_mm: float = 0.02
    compliance: bool = True
    thermal: bool = True
    temp_c: float = 20.0
    base_error_mm: float = 1.0
    base_error_rad: float = 5e-4
    mount_error_mm: float = 0.5
    mount_error_rad: float = 2e-3


def _small_pose(rng: np.random.Generator, sigma_mm: float, sigma_rad: float) -> F64:
    rv = rng.normal(0.0, sigma_rad, 3)
    angle = float(np.linalg.norm(rv))
    axis = rv / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    return homogeneous(_rot(axis, np.array(angle)), rng.normal(0.0, sigma_mm, 3))


class SimulatedCell:
    """The true cell. `temp_c` may be changed between measurements (thermal drift)."""

    def __init__(self, spec: CellSpec, settings: SimSettings | None = None) -> None:
        self.spec = spec
        self.settings = settings or SimSettings()
        rng = np.random.default_rng(self.settings.seed)
        robot = TrueRobot.perturbed(rng)
        if not self.settings.compliance:
            robot = replace(robot, compliance_rad_per_nm=(0.0, 0.0))
        if not self.settings.thermal:
            robot = replace(robot, expansion_per_k=0.0)
        self.robot = robot
        s = self.settings
        self.T_part_world = spec.T_part_base @ _small_pose(rng, s.base_error_mm, s.base_error_rad)
        self.T_tool0_sensor = spec.T_flange_sensor @ _small_pose(
            rng, s.mount_error_mm, s.mount_error_rad
        )
        self.temp_c = s.temp_c
        self._noise = np.random.default_rng([s.seed, 1])
        self._spheres = {k: np.asarray(v, dtype=float) for k, v in spec.spheres_part_mm.items()}
        self._q_deg = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
        self._lock = threading.Lock()  # device fakes call from their own threads

    # -- truth ---------------------------------------------------------------------------
    def T_part_sensor(self, q_deg: ArrayLike) -> F64:
        """True sensor poses (N, 4, 4) in the part frame for controller angles (N, 6)."""
        T_wt = self.robot.T_world_tool0(q_deg, self.temp_c)
        out: F64 = self.T_part_world @ T_wt @ self.T_tool0_sensor
        return out

    def centre_in_sensor(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> F64:
        """True sphere centres (N, 3) in the sensor frame."""
        T = self.T_part_sensor(q_deg)
        p = np.broadcast_to(np.asarray(p_part_mm, dtype=float), (T.shape[0], 3))
        R_t = np.swapaxes(T[:, :3, :3], 1, 2)
        out: F64 = np.einsum("nij,nj->ni", R_t, p - T[:, :3, 3])
        return out

    # -- instruments ---------------------------------------------------------------------
    def measure_point(self, q_deg: ArrayLike, p_part_mm: ArrayLike) -> F64:
        """One geometric sensor measurement (3,) [mm] of a sphere at p_part_mm from q_deg;
        raises NotVisible outside the measuring volume."""
        c = self.centre_in_sensor(np.atleast_2d(q_deg)[:1], p_part_mm)[0]
        if not self.spec.volume.contains(c)[0]:
            raise NotVisible(f"sphere centre at {np.round(c, 1)} mm in the sensor frame")
        out: F64 = c + self._noise.normal(0.0, self.settings.sensor_noise_mm, 3)
        return out

    def track_point(self, p_part_mm: ArrayLike) -> F64:
        """Laser-tracker measurement (3,) [mm] of a point in the part frame."""
        p = np.asarray(p_part_mm, dtype=float)
        out: F64 = p + self._noise.normal(0.0, self.settings.tracker_noise_mm, 3)
        return out

    # -- the World protocol of the device fakes --------------------------------------------
    def set_joints_deg(self, q_deg: ArrayLike) -> None:
        q = np.asarray(q_deg, dtype=float).reshape(6).copy()
        with self._lock:
            self._q_deg = q

    def joints_deg(self) -> F64:
        with self._lock:
            return self._q_deg.copy()

    def target_ids(self) -> list[str]:
        return sorted(self._spheres)

    def target_true_mm(self, target_id: str) -> F64:
        return self._spheres[target_id].copy()

    def measure_target(self, target_id: str) -> F64:
        """Sensor measurement of a named sphere from the current joints."""
        return self.measure_point(self.joints_deg(), self._spheres[target_id])
