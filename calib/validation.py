"""Validation statistics (paper Eq. 19): Euclidean errors between the positions the system
computes in the part frame and the tracker's, at validation positions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]


def rmse(errors: ArrayLike) -> float:
    """RMS of the Euclidean lengths of error vectors (..., 3), in their unit (the paper's
    RMSE, Eq. 19)."""
    e = np.asarray(errors, dtype=float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of error vectors (n, 3) [mm]: RMSE, mean, max and median of the Euclidean
    error, per-axis RMS and mean."""

    n: int
    rmse_mm: float
    mean_mm: float
    median_mm: float
    max_mm: float
    axis_rms_mm: tuple[float, float, float]
    axis_mean_mm: tuple[float, float, float]

    @staticmethod
    def of(errors_mm: F64) -> ErrorStats:
        e = np.asarray(errors_mm, dtype=float).reshape(-1, 3)
        d = np.linalg.norm(e, axis=1)
        rms = np.sqrt(np.mean(e**2, axis=0))
        mean = np.mean(e, axis=0)
        return ErrorStats(
            n=int(e.shape[0]),
            rmse_mm=rmse(e),
            mean_mm=float(np.mean(d)),
            median_mm=float(np.median(d)),
            max_mm=float(np.max(d)),
            axis_rms_mm=(float(rms[0]), float(rms[1]), float(rms[2])),
            axis_mean_mm=(float(mean[0]), float(mean[1]), float(mean[2])),
        )
