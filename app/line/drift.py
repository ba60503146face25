"""Drift watch: every measurement's residual against its known sphere, with the parameters in
force, charted by EWMA and CUSUM per sphere and overall.

The residual e = |T_part_sensor(q; x) c - p| [mm] (calib.model.SystemModel.points_part) of a
good calibration is small noise; warm-up, wear or a knock shift it up. Each chart learns its
in-control mean mu and sigma from its first `baseline_n` samples after a calibration is applied
(`reset`), then watches (upper side only: a smaller residual is no alarm):

- EWMA z_t = lambda e_t + (1 - lambda) z_{t-1}, z_0 = mu; signal when
  z_t > mu + L sigma sqrt(lambda / (2 - lambda) (1 - (1 - lambda)^(2t)))
  (lambda 0.2, L 3: the REFERENCE.md limits, with the exact start-up factor);
- CUSUM S_t = max(0, S_{t-1} + e_t - mu - k sigma); signal when S_t > h sigma (k 0.5, h 5:
  a 1-sigma step flagged in about 10 samples, a 3-sigma step in 2-3).

A chart signals once and stays "drifting" until the next reset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from app.line.settings import DriftSettings
from calib.model import SystemModel

OVERALL = "*"


def residual_mm(
    model: SystemModel, x: ArrayLike, q_deg: ArrayLike, c_sensor_mm: ArrayLike, p_part_mm: ArrayLike
) -> float:
    """Distance [mm] between the measured sphere centre mapped to the part frame with the
    parameters x and the sphere's known centre."""
    p = model.points_part(
        np.asarray(x, float),
        np.asarray(q_deg, float).reshape(1, 6),
        np.asarray(c_sensor_mm, float).reshape(1, 3),
    )
    return float(np.linalg.norm(p.reshape(3) - np.asarray(p_part_mm, float)))


@dataclass(frozen=True)
class DriftSignal:
    """A chart (`stream`: a sphere id or "*" overall) left its limits (`chart`: ewma or cusum)
    at this sample, with the statistic and its limit [mm]."""

    stream: str
    chart: str
    value_mm: float
    limit_mm: float
    mu_mm: float
    sigma_mm: float


@dataclass
class Chart:
    """EWMA and CUSUM of one stream of residuals."""

    settings: DriftSettings
    baseline: list[float] = field(default_factory=list)
    mu: float = 0.0
    sigma: float = 0.0
    z: float = 0.0
    s_hi: float = 0.0
    t: int = 0
    drifting: bool = False

    def update(self, stream: str, e_mm: float) -> DriftSignal | None:
        s = self.settings
        if len(self.baseline) < s.baseline_n:
            self.baseline.append(e_mm)
            if len(self.baseline) == s.baseline_n:
                self.mu = float(np.mean(self.baseline))
                self.sigma = max(float(np.std(self.baseline, ddof=1)), s.min_sigma_mm)
                self.z = self.mu
            return None
        self.t += 1
        lam = s.ewma_lambda
        self.z = lam * e_mm + (1.0 - lam) * self.z
        spread = np.sqrt(lam / (2.0 - lam) * (1.0 - (1.0 - lam) ** (2 * self.t)))
        ewma_limit = self.mu + s.ewma_l * self.sigma * float(spread)
        self.s_hi = max(0.0, self.s_hi + e_mm - self.mu - s.cusum_k * self.sigma)
        cusum_limit = s.cusum_h * self.sigma
        if self.drifting:
            return None
        if self.s_hi > cusum_limit:
            self.drifting = True
            return DriftSignal(stream, "cusum", self.s_hi, cusum_limit, self.mu, self.sigma)
        if self.z > ewma_limit:
            self.drifting = True
            return DriftSignal(stream, "ewma", self.z, ewma_limit, self.mu, self.sigma)
        return None


class DriftMonitor:
    """Charts per sphere and overall ("*")."""

    def __init__(self, settings: DriftSettings | None = None) -> None:
        self.settings = settings or DriftSettings()
        self.charts: dict[str, Chart] = {}

    def reset(self) -> None:
        """New parameters are in force: learn every baseline again."""
        self.charts.clear()

    def update(self, target: str, e_mm: float) -> list[DriftSignal]:
        """Feed one residual; the signals it raised (at most one per stream)."""
        out = []
        for stream in (target, OVERALL):
            chart = self.charts.setdefault(stream, Chart(self.settings))
            signal = chart.update(stream, e_mm)
            if signal is not None:
                out.append(signal)
        return out

    @property
    def drifting(self) -> bool:
        return any(c.drifting for c in self.charts.values())

    def state(self) -> dict[str, dict[str, float | bool]]:
        return {
            k: {
                "mu_mm": c.mu,
                "sigma_mm": c.sigma,
                "ewma_mm": c.z,
                "cusum_mm": c.s_hi,
                "drifting": c.drifting,
            }
            for k, c in list(self.charts.items())  # read from the control socket's threads
        }
