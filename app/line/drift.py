"""Drift watch: two families of EWMA and CUSUM charts, per sphere and overall.

**Residual** charts watch e = |T_part_sensor(q; x) c - p| [mm] (SystemModel.points_part), the
distance of each measured sphere centre, mapped with the parameters in force, from the sphere's
known centre: warm-up and wear make the parameters stale and e grows. Their in-control mean mu and
sigma come, when parameters are applied, from the residuals of the calibration's own rolling set
with the new parameters (`reset(seed)`): every configuration of the schedule at once, so the
charts watch from the first measurement after an apply instead of learning a baseline from the
next (possibly already knocked) measurements. A residual the fit was trained on underestimates a
new one at the same configuration: for a least-squares fit of n parameters to m equations the
expected squared residual is sigma^2 (m - n), a new measurement's prediction error at the same
points sigma^2 (m + n); the service scales the training residuals by sqrt((m + n) / (m - n))
(`prediction_inflation`). Without a seed (the commissioning parameters of a new cell, a reset)
a chart learns mu and sigma from its first `baseline_n` samples, and is self-starting meanwhile
(Hawkins 1987: from the third sample each one is judged against those before it,
`self_start_score` of the norms' 2/3 power, and a CUSUM of the scores signals), so a knock in
the first schedule cycle is flagged as a step, never learned into the baseline.

**Change** charts watch d = |c_t - c_prev| [mm]: how far the measured centre (sensor frame) moved
since the previous visit of the same schedule slot (the same joint configuration, the same
sphere). d does not depend on the parameters at all (the same T_part_sensor maps both), so a step
of the cell (a knock of the sensor mount, a moved sphere) shows as soon as the first configuration
is measured again, whatever was applied in between; the baseline (sensor noise, robot
repeatability and the slow drift over one schedule cycle) is learned from the first
`baseline_n` differences, and learned again at every apply from the last `baseline_n`
in-control ones (a baseline of the first hour holds the warm-up's fast drift: measured, its
mean 0.065 mm against 0.045 mm at 2.5 h, so that a 0.17 mm knock needed a second sample).

Both use the REFERENCE.md limits (upper side only: a smaller statistic is no alarm):

- EWMA z_t = lambda e_t + (1 - lambda) z_{t-1}, z_0 = mu; signal when
  z_t > mu + L sigma sqrt(lambda / (2 - lambda) (1 - (1 - lambda)^(2t)))
  (lambda 0.2, L 3, with the exact start-up factor);
- CUSUM S_t = max(0, S_{t-1} + e_t - mu - k sigma); signal when S_t > h sigma (k 0.5, h 5:
  a 1-sigma step flagged in about 10 samples, a 3-sigma step in 2-3).

A chart signals once and stays "drifting" until restarted. Every signal carries the change point
estimate of the CUSUM (the first sample after S was last zero), as the caller's reference (a
measurement id): the recalibration after a step uses only measurements from there on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from app.config.line import DriftSettings
from calib.model import SystemModel

OVERALL = "*"


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
    prediction error of a new measurement at the same configurations (module docstring)."""
    if m_equations <= n_parameters:
        raise ValueError(f"{m_equations} equations for {n_parameters} parameters")
    return float(np.sqrt((m_equations + n_parameters) / (m_equations - n_parameters)))


@dataclass(frozen=True)
class DriftSignal:
    """A chart (`family`: residual or change; `stream`: a sphere id or "*" overall) left its
    limits (`chart`: ewma or cusum) at this sample, with the statistic and its limit [mm] and
    the change point estimate (`onset_ref`: the caller's reference of the first sample after
    the CUSUM was last zero)."""

    family: str
    stream: str
    chart: str
    value_mm: float
    limit_mm: float
    mu_mm: float
    sigma_mm: float
    onset_ref: int


@dataclass
class Chart:
    """EWMA and CUSUM of one stream."""

    settings: DriftSettings
    baseline: list[float] = field(default_factory=list)
    mu: float = 0.0
    sigma: float = 0.0
    z: float = 0.0
    s_hi: float = 0.0
    t: int = 0
    drifting: bool = False
    onset_ref: int = -1  # first sample after the CUSUM was last zero
    ready: bool = False  # mu and sigma known
    recent: list[float] = field(default_factory=list)  # the last in-control samples
    ss: float = 0.0  # the self-starting CUSUM while learning [standard normal scores]
    jumped: bool = False  # a sample since it was last zero stood out on its own

    def seed(self, samples: list[float], sigma_floor_mm: float = 0.0) -> None:
        """Take mu and sigma (at least `sigma_floor_mm`) from these samples (at least 2) at
        once, and watch."""
        if len(samples) < 2:
            raise ValueError("a baseline needs at least 2 samples")
        self.baseline, self.ready = list(samples), True
        self.mu = float(np.mean(samples))
        sigma = float(np.std(samples, ddof=1))
        self.sigma = max(sigma, self.settings.min_sigma_mm, sigma_floor_mm)
        self.restart()

    def restart(self) -> None:
        """Keep the baseline, restart the statistics."""
        self.z, self.s_hi, self.t, self.drifting = self.mu, 0.0, 0, False
        self.ss, self.jumped = 0.0, False

    def update(self, family: str, stream: str, e_mm: float, ref: int) -> DriftSignal | None:
        s = self.settings
        if not self.ready:
            return self._learn(family, stream, e_mm, ref)
        self.t += 1
        lam = s.ewma_lambda
        self.z = lam * e_mm + (1.0 - lam) * self.z
        spread = np.sqrt(lam / (2.0 - lam) * (1.0 - (1.0 - lam) ** (2 * self.t)))
        ewma_limit = self.mu + s.ewma_l * self.sigma * float(spread)
        if self.s_hi == 0.0:
            self.onset_ref = ref
        self.s_hi = max(0.0, self.s_hi + e_mm - self.mu - s.cusum_k * self.sigma)
        cusum_limit = s.cusum_h * self.sigma
        if self.drifting:
            return None
        tests = (("cusum", self.s_hi, cusum_limit), ("ewma", self.z, ewma_limit))
        for chart, value, limit in tests:
            if value > limit:
                self.drifting = True
                onset = self.onset_ref if self.s_hi > 0.0 else ref
                return DriftSignal(family, stream, chart, value, limit, self.mu, self.sigma, onset)
        self.recent = [*self.recent, e_mm][-s.baseline_n :]
        return None

    def _learn(self, family: str, stream: str, e_mm: float, ref: int) -> DriftSignal | None:
        """While the baseline is learned, the self-starting CUSUM (Hawkins 1987): from the
        `SELF_START_N`-th sample on each new sample is judged against the ones before it
        (`self_start_score`) and the scores feed an upper CUSUM (slack k, decision h, as the
        learned chart's), so a step is a step from the first samples and a signalling sample
        never enters the baseline. When the baseline is complete the chart watches with it."""
        s = self.settings
        if self.drifting:
            return None
        if len(self.baseline) >= SELF_START_N - 1:
            prior = np.asarray(self.baseline, float)
            mean = float(np.mean(prior))
            sd = max(float(np.std(prior, ddof=1)), s.min_sigma_mm)
            # the sigma floor carried into the transformed scale (d(e^p) = p e^(p-1) de)
            floor = NORM_POWER * max(mean, s.min_sigma_mm) ** (NORM_POWER - 1) * s.min_sigma_mm
            score = self_start_score(e_mm**NORM_POWER, prior**NORM_POWER, floor)
            # the change point: the first sample after the CUSUM was last zero, or the first
            # one since that stood out on its own (the CUSUM of a warm-up's noise is rarely
            # zero, and a knock's first sample is far out)
            if self.ss == 0.0 or (score > ONSET_SCORE and not self.jumped):
                self.onset_ref, self.jumped = ref, score > ONSET_SCORE
            self.ss = max(0.0, self.ss + score - s.cusum_k)
            if self.ss == 0.0:
                self.jumped = False
            if self.ss > s.cusum_h:
                self.drifting = True
                onset = self.onset_ref
                return DriftSignal(
                    family, stream, "cusum", self.ss * sd, s.cusum_h * sd, mean, sd, onset
                )
            if score > ONSET_SCORE:
                return None  # far out on its own: not in the baseline (a knock's first sample)
        self.baseline.append(e_mm)
        if len(self.baseline) >= s.baseline_n:
            self.seed(self.baseline)
        return None

    def relearn(self) -> None:
        """Learn the baseline again from the last in-control samples (when there are
        `baseline_n` of them), else keep it; restart the statistics either way."""
        if len(self.recent) >= self.settings.baseline_n:
            self.seed(list(self.recent))
        else:
            self.restart()

    def to_json(self) -> dict[str, Any]:
        """Everything but the settings (the service's decision state, app.line.store)."""
        return {k: getattr(self, k) for k in _CHART_FIELDS}

    def load_json(self, doc: dict[str, Any]) -> None:
        older = {
            "recent": [],
            "ss": 0.0,
            "jumped": False,
        }  # a state saved by an older version lacks these
        for k in _CHART_FIELDS:
            setattr(self, k, doc.get(k, older[k]) if k in older else doc[k])

    def state(self) -> dict[str, float | bool | None]:
        return {
            "mu_mm": self.mu,
            "sigma_mm": self.sigma,
            "ewma_mm": self.z if self.ready else None,  # None while it learns its baseline
            "learning": not self.ready,
            "cusum_mm": self.s_hi,
            "drifting": self.drifting,
        }


#: the self-starting chart judges a sample against at least this many before it, less one
SELF_START_N = 3
#: the self-starting scores are of norm^(2/3): the norm of a 3-D normal error is skewed (its
#: square chi-square with 3 degrees of freedom), its 2/3 power nearly normal (Wilson-Hilferty);
#: measured on in-control norms over 24 samples: 1.7 % false signals against 3.0 % on the raw
#: norm, a 5-sigma step flagged one sample later (3 instead of 2, median)
NORM_POWER = 2.0 / 3.0
#: a self-starting score above this (one-sided p about 0.001) marks a change point on its own
ONSET_SCORE = 3.0
#: a score's magnitude is capped (a sample far out signals at once; the cap keeps one
#: outlier's weight finite in the CUSUM's memory)
SCORE_CAP = 8.0


def self_start_score(e_mm: float, prior: ArrayLike, min_sigma_mm: float = 0.0) -> float:
    """The sample `e_mm` standardised by the n samples before it (Hawkins 1987, Quesenberry's
    Q statistic): t = (e - mean) / (s sqrt(1 + 1/n)) is Student t with n - 1 degrees of freedom
    when all n + 1 come from one normal distribution; its probability turned into a standard
    normal score (capped at +-SCORE_CAP). s is at least `min_sigma_mm` (a noise-free start)."""
    from scipy.stats import norm
    from scipy.stats import t as t_dist

    x = np.asarray(prior, float)
    n = len(x)
    if n < 2:
        raise ValueError("a self-starting score needs at least 2 samples before it")
    sd = max(float(np.std(x, ddof=1)), min_sigma_mm)
    t = (e_mm - float(np.mean(x))) / (sd * np.sqrt(1.0 + 1.0 / n))
    # the upper tail's probability, well resolved where the chart decides
    z = float(-norm.ppf(t_dist.sf(t, n - 1))) if t > 0 else float(norm.ppf(t_dist.cdf(t, n - 1)))
    return float(np.clip(z, -SCORE_CAP, SCORE_CAP))


_CHART_FIELDS = (
    "baseline",
    "mu",
    "sigma",
    "z",
    "s_hi",
    "t",
    "drifting",
    "onset_ref",
    "ready",
    "recent",
    "ss",
    "jumped",
)


class ChartFamily:
    """Charts of one statistic per sphere and overall ("*")."""

    def __init__(self, family: str, settings: DriftSettings) -> None:
        self.family, self.settings = family, settings
        self.charts: dict[str, Chart] = {}

    def update(self, target: str, value_mm: float, ref: int) -> list[DriftSignal]:
        out = []
        for stream in (target, OVERALL):
            chart = self.charts.setdefault(stream, Chart(self.settings))
            signal = chart.update(self.family, stream, value_mm, ref)
            if signal is not None:
                out.append(signal)
        return out

    @property
    def drifting(self) -> bool:
        return any(c.drifting for c in self.charts.values())

    def state(self) -> dict[str, dict[str, float | bool | None]]:
        return {k: c.state() for k, c in list(self.charts.items())}  # read by other threads

    def to_json(self) -> dict[str, dict[str, Any]]:
        return {k: c.to_json() for k, c in self.charts.items()}

    def load_json(self, doc: dict[str, dict[str, Any]]) -> None:
        self.charts.clear()
        for stream, chart_doc in doc.items():
            self.charts[stream] = chart = Chart(self.settings)
            chart.load_json(chart_doc)


class DriftMonitor:
    """The residual and the change charts (module docstring)."""

    def __init__(
        self, settings: DriftSettings | None = None, *, residual_baseline_n: int = 0
    ) -> None:
        """`residual_baseline_n`: a learned residual baseline spans at least this many samples
        (the schedule's length, so that it holds every configuration's level)."""
        self.settings = settings or DriftSettings()
        n = max(self.settings.baseline_n, residual_baseline_n)
        self.residual = ChartFamily("residual", replace(self.settings, baseline_n=n))
        self.change = ChartFamily("change", self.settings)

    def reset(self, seed: Sequence[tuple[str, float]] = ()) -> None:
        """New parameters are in force: the residual charts start again, seeded with the new
        parameters' residuals `seed` (target, e_mm) when given (a sphere with fewer than
        `baseline_n` of them keeps its own mean but takes at least the pooled sigma: 6 samples
        give sigma +-30 %), else they learn; the change charts learn their baseline again from
        their last in-control differences (`Chart.relearn`)."""
        self.residual.charts.clear()
        streams: dict[str, list[float]] = {OVERALL: []}
        for target, e_mm in seed:
            streams.setdefault(target, []).append(float(e_mm))
            streams[OVERALL].append(float(e_mm))
        pooled = streams[OVERALL]
        if len(pooled) >= 2:
            sigma_pooled = float(np.std(pooled, ddof=1))
            for stream, samples in streams.items():
                few = len(samples) < self.settings.baseline_n
                self.residual.charts[stream] = chart = Chart(self.residual.settings)
                chart.seed(samples if len(samples) >= 2 else pooled, sigma_pooled if few else 0.0)
        self._restart_change()

    def restart(self) -> None:
        """Parameters close to those in force were applied (a sequential estimator's small
        step): every residual chart keeps its baseline and restarts its statistics; the change
        charts learn theirs again (`Chart.relearn`)."""
        for chart in self.residual.charts.values():
            chart.restart()
        self._restart_change()

    def _restart_change(self) -> None:
        for chart in self.change.charts.values():
            chart.relearn()

    def update(
        self, target: str, e_mm: float, ref: int, change_mm: float | None = None
    ) -> list[DriftSignal]:
        """Feed one measurement's residual (and its change since the slot's previous visit, if
        there is one); the signals it raised (at most one per chart)."""
        out = self.residual.update(target, e_mm, ref)
        if change_mm is not None:
            out += self.change.update(target, change_mm, ref)
        return out

    @property
    def drifting(self) -> bool:
        return self.residual.drifting or self.change.drifting

    @property
    def change_watching(self) -> bool:
        """The overall change chart has its baseline (a step would show there)."""
        chart = self.change.charts.get(OVERALL)
        return chart is not None and chart.ready

    def to_json(self) -> dict[str, Any]:
        """Both families' charts, statistics and baselines (restored by `load_json`)."""
        return {"residual": self.residual.to_json(), "change": self.change.to_json()}

    def load_json(self, doc: dict[str, Any]) -> None:
        self.residual.load_json(doc["residual"])
        self.change.load_json(doc["change"])

    def state(self) -> dict[str, dict[str, float | bool | None]]:
        """The residual charts (the status reply's `drift`)."""
        return self.residual.state()

    def change_state(self) -> dict[str, dict[str, float | bool | None]]:
        """The change charts (the status reply's `drift_change`)."""
        return self.change.state()
