"""The sensor's own health in-line: the probing error size PS of every measurement, charted.

Every rendered measurement fits the sphere with a free radius as a health check
(vision.spherefit); PS = 2 (free radius - certified radius) is VDI/VDE 2634-2's probing error
size, measured on the certified sphere at every visit. It does not depend on the robot or the
kinematic parameters at all, so a change in it says the *sensor* changed (its calibration no
longer fits the optics, the laser or the galvo), not the robot. Two signals, each raising the
`sensor` alarm once:

- the EWMA of PS (lambda of `[drift]`) beyond the acceptance limit `[sensor] max_ps_mm`: the
  sensor no longer meets its acceptance (a sensor commissioned with an error from the start
  shows here); re-armed when the EWMA is back within half the limit;
- a two-sided CUSUM (k 0.5 sigma, h of `[drift]`: 10) of PS against its own baseline (mean
  and sigma of the first `[drift] baseline_n` values, 100: every view of the schedule several
  times; sigma at least `MIN_SIGMA_MM`): a shift of the sensor within its limits; learned
  again after a signal. Its false alarms: app/config/line.py's DriftSettings.

The watch is rebuilt at start from the stored measurements (`replay`), so a restarted service
charts as one that never stopped. Measurements without a free fit (the geometric path) are not
charted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from vision.acceptance import probing_size_mm

#: The floor of PS's in-control sigma [mm]: a noise-free (geometric or replayed) baseline must
#: not make every micrometre a shift.
MIN_SIGMA_MM = 0.002
#: The CUSUM's slack [sigma].
CUSUM_K = 0.5


@dataclass
class SensorWatch:
    """PS charts (module docstring): limit_mm the acceptance limit, lam the EWMA's lambda,
    h the CUSUM's decision interval [sigma], baseline_n the values that set the baseline."""

    limit_mm: float
    lam: float = 0.2
    h: float = 10.0
    baseline_n: int = 100
    n: int = 0
    ewma_mm: float = math.nan
    ewma_signalled: bool = False
    baseline: list[float] = field(default_factory=list)
    mean_mm: float = math.nan
    sigma_mm: float = math.nan
    s_hi: float = 0.0
    s_lo: float = 0.0

    @staticmethod
    def ps_of(quality: dict[str, Any]) -> float | None:
        """PS [mm] of a measurement's quality figures (None without a free fit)."""
        dev = quality.get("radius_dev_mm")  # r_free - r_certified (vision.spherefit)
        if dev is None or "radius_free_mm" not in quality:
            return None
        free = float(quality["radius_free_mm"])
        return float(probing_size_mm(free, free - float(dev)))

    def update(self, ps_mm: float) -> str | None:
        """Chart one PS [mm]; the alarm's text when this value makes a signal, else None."""
        self.n += 1
        self.ewma_mm = ps_mm if self.n == 1 else self.lam * ps_mm + (1 - self.lam) * self.ewma_mm
        out = self._ewma_signal()
        shift = self._cusum(ps_mm)
        return out or shift

    def _ewma_signal(self) -> str | None:
        beyond = abs(self.ewma_mm) > self.limit_mm
        if self.ewma_signalled and abs(self.ewma_mm) <= 0.5 * self.limit_mm:
            self.ewma_signalled = False
        if not beyond or self.ewma_signalled or self.n < 3:
            return None
        self.ewma_signalled = True
        return (
            f"the sensor measures the certified sphere {1000 * self.ewma_mm:+.1f} um off in "
            f"diameter (PS, EWMA of {self.n}), beyond its acceptance +-{1000 * self.limit_mm:.1f}"
            " um: the sensor changed (calibration, optics, laser or galvo), not the robot;"
            " verify it (rvis sensor verify)"
        )

    def _cusum(self, ps_mm: float) -> str | None:
        if len(self.baseline) < self.baseline_n:
            self.baseline.append(ps_mm)
            if len(self.baseline) == self.baseline_n:
                m = sum(self.baseline) / len(self.baseline)
                var = sum((v - m) ** 2 for v in self.baseline) / max(len(self.baseline) - 1, 1)
                self.mean_mm, self.sigma_mm = m, max(math.sqrt(var), MIN_SIGMA_MM)
            return None
        z = (ps_mm - self.mean_mm) / self.sigma_mm
        self.s_hi = max(0.0, self.s_hi + z - CUSUM_K)
        self.s_lo = max(0.0, self.s_lo - z - CUSUM_K)
        if max(self.s_hi, self.s_lo) <= self.h:
            return None
        text = (
            f"the sensor's PS shifted from its baseline {1000 * self.mean_mm:+.1f} um "
            f"(sigma {1000 * self.sigma_mm:.1f} um) to {1000 * ps_mm:+.1f} um (CUSUM): the "
            "sensor changed, not the robot; verify it (rvis sensor verify)"
        )
        self.baseline, self.s_hi, self.s_lo = [], 0.0, 0.0
        return text

    def replay(self, qualities: list[dict[str, Any]]) -> None:
        """Chart stored measurements again without signalling (a restart's catch-up)."""
        for q in qualities:
            ps = self.ps_of(q)
            if ps is not None:
                self.update(ps)
        if not math.isnan(self.ewma_mm) and abs(self.ewma_mm) > self.limit_mm:
            self.ewma_signalled = True  # its alarm was raised before the restart
