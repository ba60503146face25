"""The plan's views after a maintenance: each view re-aimed so that the sensor sees its sphere
as planned (the planned centre in the sensor frame, the planned orientation) on the parameters
now, at the sphere's place now; and an axis's zero moved in a parameter vector."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from calib import robot
from calib.ik_refine import refine, sensor_target
from calib.model import INDEX, SystemModel

F64 = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def reaim(
    model: SystemModel,
    x_plan: F64,
    x_now: F64,
    q_plan_deg: F64,
    c_plan_mm: F64,
    p_now_mm: F64,
) -> tuple[F64, BoolArray]:
    """Configurations (K, 6) [deg] that put each sphere, now at p_now_mm (K, 3) in the part
    frame, at its planned centre c_plan_mm (K, 3) in the sensor frame with the orientation the
    plan's configuration q_plan_deg (K, 6) had on x_plan, on the parameters x_now; and whether
    each converged within the joint limits. `model` is the rigid chain the plan was made on."""
    R_plan = model.fk(x_plan, q_plan_deg)[:, :3, :3]
    target = sensor_target(p_now_mm, c_plan_mm, R_plan)
    out = refine(model, x_now, target, q_plan_deg, max_iter=20)
    return out.q_deg, out.converged


def zero_moved(x: F64, axis: int, delta_deg: float) -> F64:
    """x with the controller zero of `axis` (1..6) moved by delta_deg: through the J2/J3
    coupling a J2 zero moves theta2 and theta3 (calib/robot.py)."""
    out = np.array(x, dtype=float)
    dq = np.zeros(6)
    dq[axis - 1] = np.radians(delta_deg)
    dtheta = robot.COUPLING @ dq
    for i in range(6):
        out[INDEX[f"dtheta{i + 1}"]] += dtheta[i]
    return out


def zero_of(x: F64, x_before: F64, axis: int) -> float:
    """The controller zero change of `axis` [deg] from x_before to x (the thetas' change
    mapped back through the coupling)."""
    cols = [INDEX[f"dtheta{i}"] for i in range(1, 7)]
    dq = robot.COUPLING_INV @ (np.asarray(x)[cols] - np.asarray(x_before)[cols])
    return float(np.degrees(dq[axis - 1]))
