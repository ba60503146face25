"""Sequential (extended Kalman / recursive least-squares) estimation of the model parameters,
one sphere measurement at a time, for the in-line case.

State: the active parameters x_a (L,) with covariance P (L, L). Each `update`:

    predict   P <- P + Q                        Q = diag(drift^2): random-walk drift per update
    innovate  r = p_tracker - P_model(x; q, c, T)  (3,) [mm],  H = dP_model/dx_a (3, L)
              S = H P H^T + sigma^2 I3,  d2 = r^T S^-1 r
    gate      d2 > gate_chi2 (chi-square, 3 dof): rejected, x unchanged; after
              `knock_after` rejections in a row the model is taken to have changed (a knock,
              a crash, a fixture moved): P grows by diag(knock^2) so that the next
              measurements can pull the estimate to the new state
    correct   K = P H^T S^-1,  x_a <- x_a + K r,  P <- (I - K H) P (I - K H)^T + K R K^T

The model is relinearised at the current estimate on every update (extended Kalman filter);
with Q = 0 it is recursive least squares with the prior as regulariser. The Joseph form keeps
P symmetric positive definite in floating point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calib.errors import InsufficientData
from calib.identify import IdentificationResult
from calib.model import INDEX, SystemModel, check_active, unit_of

F64 = NDArray[np.float64]
#: chi-square quantile, 3 degrees of freedom, p = 0.999
CHI2_3DOF_999 = 16.266


@dataclass(frozen=True)
class SequentialSettings:
    """measurement_std_mm: standard deviation of one coordinate of a measured centre (sensor
    and tracker together); gate_chi2: Mahalanobis gate on the squared innovation; the drift
    standard deviations per update of the length [mm], angle [rad] and extra (compliance
    [rad/m], expansion [1/K]) parameters model slow changes (warm-up, wear); knock_after
    rejections in a row (0: never) add knock_mm / knock_rad to the parameters' standard
    deviations (a sudden change)."""

    measurement_std_mm: float = 0.025
    gate_chi2: float = CHI2_3DOF_999
    drift_mm: float = 0.0
    drift_rad: float = 0.0
    drift_extra: float = 0.0
    knock_after: int = 5
    knock_mm: float = 1.0
    knock_rad: float = 1e-3

    def __post_init__(self) -> None:
        if not self.measurement_std_mm > 0.0 or not self.gate_chi2 > 0.0:
            raise ValueError("measurement_std_mm and gate_chi2 must be > 0")
        if min(self.drift_mm, self.drift_rad, self.drift_extra) < 0.0:
            raise ValueError("drift standard deviations must be >= 0")
        if self.knock_after < 0 or min(self.knock_mm, self.knock_rad) < 0.0:
            raise ValueError("knock_after, knock_mm and knock_rad must be >= 0")


@dataclass(frozen=True)
class Update:
    """What one update did: accepted or rejected by the gate, the squared Mahalanobis distance
    of the innovation, the innovation (3,) [mm] before the correction; `knock`: this
    rejection completed a run of `knock_after` and the covariance was widened."""

    accepted: bool
    mahalanobis2: float
    innovation_mm: F64
    knock: bool = False


class SequentialEstimator:
    """Kalman / RLS estimator of a model's active parameters (module docstring).

    x0: full parameter vector of the model; P0: covariance (L, L) of the active ones.
    Not thread-safe: one owner (e.g. the service's cycle) calls `update`."""

    def __init__(
        self,
        model: SystemModel,
        x0: F64,
        active: Sequence[str],
        P0: F64,
        settings: SequentialSettings | None = None,
    ) -> None:
        self.model = model
        self.active = check_active(active, model.names)
        self.settings = settings or SequentialSettings()
        self._x = np.array(x0, dtype=float)
        self._cols = np.array([INDEX[n] for n in self.active])
        self._P = np.array(P0, dtype=float)
        L = len(self.active)
        if self._x.shape != (len(model.names),) or self._P.shape != (L, L):
            raise InsufficientData(
                f"x0 needs shape ({len(model.names)},), P0 ({L}, {L}); "
                f"got {self._x.shape}, {self._P.shape}"
            )
        s = self.settings
        self._Q = np.diag(self._by_unit(s.drift_mm, s.drift_rad, s.drift_extra) ** 2)
        self._knock = np.diag(self._by_unit(s.knock_mm, s.knock_rad, 0.0) ** 2)
        self._R = np.eye(3) * self.settings.measurement_std_mm**2
        self.n_accepted = 0
        self.n_rejected = 0
        self.n_knocks = 0
        self._in_a_row = 0

    @staticmethod
    def from_result(
        model: SystemModel,
        result: IdentificationResult,
        settings: SequentialSettings | None = None,
    ) -> SequentialEstimator:
        """Start from a batch identification: its parameters and their covariance."""
        P0 = result.corr * np.outer(result.std, result.std)
        return SequentialEstimator(model, result.x, result.active, P0, settings)

    @staticmethod
    def from_prior(
        model: SystemModel,
        x0: F64,
        active: Sequence[str],
        std_mm: float = 2.0,
        std_rad: float = 5e-3,
        std_extra: float = 1e-4,
        settings: SequentialSettings | None = None,
    ) -> SequentialEstimator:
        """Start from x0 with independent prior standard deviations by unit."""
        std = np.array([_by_unit(n, std_mm, std_rad, std_extra) for n in active])
        return SequentialEstimator(model, x0, active, np.diag(std**2), settings)

    def _by_unit(self, mm: float, rad: float, extra: float) -> F64:
        return np.array([_by_unit(n, mm, rad, extra) for n in self.active])

    # -- state ---------------------------------------------------------------------------
    @property
    def x(self) -> F64:
        """The current full parameter vector (a copy)."""
        return self._x.copy()

    @property
    def covariance(self) -> F64:
        """The current covariance (L, L) of the active parameters (a copy)."""
        return self._P.copy()

    @property
    def std(self) -> F64:
        """Standard uncertainties (L,) of the active parameters."""
        out: F64 = np.sqrt(np.clip(np.diag(self._P), 0.0, None))
        return out

    # -- the update ----------------------------------------------------------------------
    def update(
        self,
        q_deg: ArrayLike,
        c_sensor_mm: ArrayLike,
        p_part_mm: ArrayLike,
        temp_c: float | None = None,
    ) -> Update:
        """One measurement: controller angles (6,) [deg], the centre in the sensor frame (3,)
        [mm], the tracker's centre in the part frame (3,) [mm], the cell temperature [degC]."""
        q = np.asarray(q_deg, dtype=float).reshape(1, 6)
        c = np.asarray(c_sensor_mm, dtype=float).reshape(1, 3)
        t = None if temp_c is None else np.array([float(temp_c)])
        P = self._P + self._Q
        p, J = self.model.point_and_jacobian(self._x, q, c, self.active, temp_c=t)
        r = np.asarray(p_part_mm, dtype=float).reshape(3) - p[0]
        H = J[0]
        PHt = P @ H.T
        S = H @ PHt + self._R
        d2 = float(r @ np.linalg.solve(S, r))
        if not np.isfinite(d2) or d2 > self.settings.gate_chi2:
            return self._reject(P, d2, r)
        self._in_a_row = 0
        K = np.linalg.solve(S, PHt.T).T
        self._x[self._cols] += K @ r
        IKH = np.eye(len(self.active)) - K @ H
        self._P = IKH @ P @ IKH.T + K @ self._R @ K.T
        self.n_accepted += 1
        return Update(True, d2, r)

    def widen(self, names: Sequence[str] | None = None) -> None:
        """The caller knows the model changed (a knock flagged elsewhere): grow P by
        diag(knock^2) now, as a run of `knock_after` rejections would; only for the active
        parameters `names` when given (the group a step was attributed to)."""
        knock = self._knock
        if names is not None:
            keep = np.isin(np.array(self.active), np.array(list(names)))
            knock = knock * np.outer(keep, keep)
        self._P = self._P + knock
        self.n_knocks += 1
        self._in_a_row = 0

    def predicted_std_mm(
        self, q_deg: ArrayLike, c_sensor_mm: ArrayLike, temp_c: ArrayLike | None = None
    ) -> float:
        """How well the current estimate predicts the part-frame point at K views (K, 6) with
        the sphere at c_sensor_mm (K, 3): the RMS over the views of sqrt(trace(H P H^T) / 3)
        [mm per coordinate], to compare with the measurement noise."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        t = None if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), q.shape[:1])
        H = self.model.point_jacobian(self._x, q, c_sensor_mm, self.active, temp_c=t)
        var = np.einsum("kil,lm,kim->k", H, self._P, H) / 3.0
        return float(np.sqrt(np.mean(var)))

    # -- adaptive scheduling -------------------------------------------------------------
    def information_gain(
        self, q_deg: ArrayLike, c_sensor_mm: ArrayLike, temp_c: ArrayLike | None = None
    ) -> F64:
        """Expected information [nats] of measuring each of K candidate views (K, 6), with
        the sphere expected at c_sensor_mm (K, 3): log det(I + H (P + Q) H^T / sigma^2), the
        reduction of log det P an accepted measurement brings (D-optimal, given the current
        covariance)."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        t = None if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), q.shape[:1])
        H = self.model.point_jacobian(self._x, q, c_sensor_mm, self.active, temp_c=t)
        S = H @ (self._P + self._Q) @ np.swapaxes(H, 1, 2)
        _, logdet = np.linalg.slogdet(np.eye(3) + S / self.settings.measurement_std_mm**2)
        out: F64 = logdet
        return out

    def choose_next(
        self, q_deg: ArrayLike, c_sensor_mm: ArrayLike, temp_c: ArrayLike | None = None
    ) -> int:
        """Index of the candidate view with the most information (adaptive scheduling
        instead of cycling the plan)."""
        return int(np.argmax(self.information_gain(q_deg, c_sensor_mm, temp_c)))

    def _reject(self, P: F64, d2: float, r: F64) -> Update:
        self.n_rejected += 1
        self._in_a_row += 1
        knock = self._in_a_row == self.settings.knock_after
        if knock:
            P = P + self._knock
            self.n_knocks += 1
            self._in_a_row = 0
        self._P = P
        return Update(False, d2, r, knock)


def _by_unit(name: str, mm: float, rad: float, extra: float) -> float:
    unit = unit_of(name)
    return mm if unit == "mm" else rad if unit == "rad" else extra
