"""Nominal FANUC M-710iC/50 (R-30iB), the one home of its data sheet: modified-DH geometry,
controller joint angles with the J2/J3 coupling, joint limits and speeds, the cell's home
position. The limits, speeds and home are plain numbers in calib/datasheet.py (the cell file's
defaults read them there without numpy); this module makes them arrays. The drivers' guard gets
them through the cell file.

Facts from REFERENCE.md (ROS-Industrial `fanuc_m710ic_support`, checked against its URDF):
the base frame B is FANUC's World frame, on the J1 axis at J2 height (565 mm above the URDF
`base_link`); the flange frame F is the URDF `tool0` (z out of the flange).

Controller (pendant) angles J1..J6 cross every boundary of rvis. Their J3 is measured from the
horizon, so the URDF joint 3 is q3 = J3 + J2; in the modified-DH (Craig) joint variables:
theta1 = J1, theta2 = J2 - 90deg, theta3 = -(J2 + J3), theta4 = -J4, theta5 = -J5,
theta6 = -J6. (REFERENCE.md lists theta6 = -J6 + 90deg; with that offset frame 6 is the URDF
`tool0` turned by +90deg about its z axis. Zero offset makes frame 6 equal `tool0`, checked
against the URDF chain in tests/calib/test_model.py.)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib import datasheet

F64 = NDArray[np.float64]

#: d1 of the URDF chain: height of the J2 axis (and of the World frame) above `base_link`.
BASE_LINK_TO_WORLD_Z_MM = 565.0

#: Modified-DH rows i = 1..6 with B at World: (alpha_{i-1} [rad], a_{i-1} [mm], d_i [mm]).
MDH_ALPHA_RAD = np.radians([0.0, -90.0, 0.0, -90.0, 90.0, -90.0])
MDH_A_MM = np.array([0.0, 150.0, 870.0, 170.0, 0.0, 0.0])
MDH_D_MM = np.array([0.0, 0.0, 0.0, 1016.0, 0.0, 175.0])

#: theta = COUPLING @ J + THETA_OFFSET (controller J in radians -> MDH theta in radians).
COUPLING = np.array(
    [
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, -1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, -1.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, -1.0],
    ]
)
THETA_OFFSET_RAD = np.radians([0.0, -90.0, 0.0, 0.0, 0.0, 0.0])
COUPLING_INV = np.linalg.inv(COUPLING)


def controller_to_theta(q_deg: ArrayLike) -> F64:
    """Controller angles (..., 6) [deg] -> modified-DH joint variables (..., 6) [rad]."""
    q = np.radians(np.asarray(q_deg, dtype=float))
    theta: F64 = q @ COUPLING.T + THETA_OFFSET_RAD
    return theta


def theta_to_controller(theta_rad: ArrayLike) -> F64:
    """Inverse of `controller_to_theta`: (..., 6) [rad] -> controller angles (..., 6) [deg]."""
    theta = np.asarray(theta_rad, dtype=float) - THETA_OFFSET_RAD
    q_deg: F64 = np.degrees(theta @ COUPLING_INV.T)
    return q_deg


@dataclass(frozen=True)
class JointLimits:
    """Controller joint limits [deg], shape (6,) each. J3 applies to the controller angle
    (measured from the horizon), as the pendant enforces it."""

    lower_deg: F64 = field(default_factory=lambda: np.array(datasheet.JOINT_LOWER_DEG))
    upper_deg: F64 = field(default_factory=lambda: np.array(datasheet.JOINT_UPPER_DEG))

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lower_deg, float), np.asarray(self.upper_deg, float)
        if lo.shape != (6,) or hi.shape != (6,) or np.any(lo >= hi):
            raise ValueError("joint limits need 6 lower < upper values [deg]")

    def contains(self, q_deg: ArrayLike, tol_deg: float = 1e-9) -> NDArray[np.bool_]:
        """True where every joint of q_deg (..., 6) lies within the limits."""
        q = np.asarray(q_deg, dtype=float)
        inside = (q >= self.lower_deg - tol_deg) & (q <= self.upper_deg + tol_deg)
        result: NDArray[np.bool_] = np.all(inside, axis=-1)
        return result

    def violations(self, q_deg: ArrayLike) -> list[str]:
        """Human-readable list of the joints of one configuration outside the limits."""
        q = np.asarray(q_deg, dtype=float)
        out = []
        for i in range(6):
            if not self.lower_deg[i] <= q[i] <= self.upper_deg[i]:
                out.append(
                    f"J{i + 1}={q[i]:.3f} deg outside "
                    f"[{self.lower_deg[i]:g}, {self.upper_deg[i]:g}]"
                )
        return out


#: Maximum joint speeds [deg/s] (calib.datasheet).
JOINT_SPEED_DEG_S = np.array(datasheet.JOINT_SPEED_DEG_S)

#: The service's home position [deg], controller angles (calib.datasheet).
HOME_DEG = np.array(datasheet.HOME_DEG)
