"""A sphere measurement's residual under the parameters in force, and the factor that turns a
least-squares fit's training residuals into the prediction errors of new measurements (the U95
seed of a version: app.line.accuracy, app.line.versions)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from calib.model import SystemModel


def residual_mm(
    model: SystemModel,
    x: ArrayLike,
    q_deg: ArrayLike,
    c_sensor_mm: ArrayLike,
    p_part_mm: ArrayLike,
    temp_c: float | None = None,
) -> float:
    """Distance [mm] between the measured sphere centre mapped to the part frame with the
    parameters x (at the cell temperature `temp_c` [degC] when the model has a thermal term)
    and the sphere's known centre."""
    p = model.points_part(
        np.asarray(x, float),
        np.asarray(q_deg, float).reshape(1, 6),
        np.asarray(c_sensor_mm, float).reshape(1, 3),
        temp_c=None if temp_c is None else np.array([float(temp_c)]),
    )
    return float(np.linalg.norm(p.reshape(3) - np.asarray(p_part_mm, float)))


def prediction_inflation(m_equations: int, n_parameters: int) -> float:
    """sqrt((m + n) / (m - n)): a least-squares fit's training residual -> the expected
    prediction error of a new measurement at the same configurations (the hat matrix's mean
    leverage n / m taken off in training and added in prediction)."""
    if m_equations <= n_parameters:
        raise ValueError(f"{m_equations} equations for {n_parameters} parameters")
    return float(np.sqrt((m_equations + n_parameters) / (m_equations - n_parameters)))
