"""SPC of the bodies' characteristics that knows gauge from process (issue 49 item 5).

An individuals chart per characteristic, as plants run them: the centre and sigma from the
first `BASELINE_N` values (sigma from the average moving range / 1.128), drawn with their
3-sigma limits (`limits_mm`). The cell charts every characteristic of every body at once (74 on
the simulated part type), so its alarm counts its false alarms per body, not per chart: with
the Western Electric rules on each chart (one value beyond 3 sigma, 2 of 3 beyond 2 sigma, 8 in
a row on one side) 74 charts of a perfectly stable process signalled 1.1 times a body
(docs/results/body.md). The alarm's two rules, on the baseline's mean m and standard deviation
s (n = BASELINE_N values), each a Student t statistic with n - 1 degrees of freedom for a stable
normal process however far m and s are from the truth (a new value, or the mean of RECENT_N
new ones, against m):

    rule 1  |x - m| / (s sqrt(1 + 1/n))                 > L
    rule 2  |mean of the last 8 - m| / (s sqrt(1/8 + 1/n)) > L   (a sustained shift)

L = `alarm_limit(family)`: each rule's two-sided tail is half of `ALPHA_BODY` (a Shewhart
chart's one false alarm in 370) shared over the body's `family` of charts (Bonferroni): on a
stable process the expected false alarms are one in 370 bodies, whatever the number of
characteristics (5.7 for 74 charts, 3.75 for one). Rule 2 looks back over `RECENT_N` values
only, so a restarted service that replays its last bodies decides as one that never stopped.

A chart that signalled stays quiet until `QUIET_N` values in a row break no rule (one excursion,
one signal). Whose is the signal, looked at after the cell's next window (it measures itself
there): the process's when the cell vouched for its accuracy over every body that raised it and
after them (the U95 it stated within the plant's limit, no suspect interval over the bodies): the
parts moved; the gauge's otherwise: the cell may have moved, and which suspect interval
(`attribute`).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

BASELINE_N = 20
#: the first bodies a chart is replayed from hold its baseline (a feature not measured in a few
#: of them included): the service's charts at a start, the operator's view of their limits
BASELINE_BODIES = 2 * BASELINE_N
#: the limits the charts are drawn with: centre +- this many sigma
LIMIT_SIGMA = 3.0
#: the alarm's expected false alarms a body of a stable process, over all its charts and rules
ALPHA_BODY = 0.0027
QUIET_N = 8
#: the values a chart's rule 2 averages and a signal's bodies look back over
RECENT_N = 8
RULES = {
    1: "a value beyond its alarm limit",
    2: f"the mean of its last {RECENT_N} values beyond its alarm limit",
}


@cache
def alarm_limit(family: int, n: int = BASELINE_N) -> float:
    """L, the rules' limit on their t statistics (module docstring) for a chart among `family`
    charted at once, its baseline of n values."""
    from scipy.special import stdtrit  # here: `rvis state` reads this module without numpy

    tail = ALPHA_BODY / 2.0 / max(int(family), 1)
    return float(stdtrit(n - 1, 1.0 - tail / 2.0))


@dataclass
class Signal:
    """A chart's signal: the characteristic, the rule, the bodies that raised it (ids and the
    measured values' times and U95 statements as stored), the chart's centre and sigma."""

    key: str
    rule: int
    bodies: list[Any]
    centre_mm: float
    sigma_mm: float

    def text(self, attribution: str) -> str:
        first, last = self.bodies[0], self.bodies[-1]
        span = f"body {first}" if first == last else f"bodies {first}-{last}"
        return (
            f"SPC {self.key}: {RULES[self.rule]} ({span}; centre {self.centre_mm:.3f} mm, sigma"
            f" {self.sigma_mm:.3f} mm): {attribution}"
        )


@dataclass
class IndividualsChart:
    """One characteristic's chart (module docstring), one of `family` charted at once."""

    key: str
    family: int = 1
    baseline: list[float] = field(default_factory=list)
    centre: float = math.nan
    sigma: float = math.nan
    sd: float = math.nan  # the baseline's standard deviation (the alarm's s)
    recent: deque[tuple[float, Any]] = field(default_factory=lambda: deque(maxlen=RECENT_N))
    quiet: int = QUIET_N

    def add(self, value: float, body: Any) -> Signal | None:
        """The next value (of body `body`); the signal it raises, if any."""
        if len(self.baseline) < BASELINE_N:
            self.baseline.append(value)
            if len(self.baseline) == BASELINE_N:
                self._limits()
            return None
        self.recent.append((value, body))
        rule = self._rule()
        if rule is None:
            self.quiet += 1
            return None
        if self.quiet < QUIET_N:
            self.quiet = 0
            return None
        self.quiet = 0
        n = {1: 1, 2: RECENT_N}[rule]
        bodies = [b for _, b in list(self.recent)[-n:]]
        return Signal(self.key, rule, bodies, self.centre, self.sigma)

    @property
    def limits_mm(self) -> tuple[float, float]:
        """The chart's drawn lower and upper control limits, 3 sigma (nan before the baseline
        is complete)."""
        return self.centre - LIMIT_SIGMA * self.sigma, self.centre + LIMIT_SIGMA * self.sigma

    def _limits(self) -> None:
        b = self.baseline
        self.centre = sum(b) / len(b)
        mr = [abs(y - x) for x, y in itertools.pairwise(b)]
        self.sigma = max(sum(mr) / len(mr) / 1.128, 1e-6)
        var = sum((x - self.centre) ** 2 for x in b) / (len(b) - 1)
        self.sd = max(math.sqrt(var), 1e-6)

    def _rule(self) -> int | None:
        n = len(self.baseline)
        limit = alarm_limit(self.family, n)
        last, _ = self.recent[-1]
        if abs(last - self.centre) / (self.sd * math.sqrt(1.0 + 1.0 / n)) > limit:
            return 1
        if len(self.recent) == RECENT_N:
            mean = sum(v for v, _ in self.recent) / RECENT_N
            if abs(mean - self.centre) / (self.sd * math.sqrt(1.0 / RECENT_N + 1.0 / n)) > limit:
                return 2
        return None


def chart_key(value: dict[str, Any]) -> str:
    """The chart of a stored value (feature, characteristic): "H01.X"."""
    return f"{value['feature']}.{value['characteristic']}"


def add_values(
    charts: dict[str, IndividualsChart], body: Any, values: Iterable[dict[str, Any]]
) -> list[Signal]:
    """A body's stored values (feature, characteristic, measured_mm) each into its chart (made
    when it is the first, one of a family of as many charts as the body has values), those not
    measured left out; the signals they raise."""
    values = list(values)
    family = len(values)  # every characteristic of the body, measured or not: charted at once
    signals = []
    for v in values:
        if v["measured_mm"] is None:
            continue
        key = chart_key(v)
        chart = charts.setdefault(key, IndividualsChart(key, family))
        signal = chart.add(float(v["measured_mm"]), body)
        if signal is not None:
            signals.append(signal)
    return signals


def suspect_of(
    body: dict[str, Any], intervals: Sequence[dict[str, Any]], now_t: float = math.inf
) -> int | None:
    """The id of the suspect interval a stored body's values stand in (None: none): measured
    inside it (an open one reaching to now_t) and not computed again with its correction
    (`body`: t, suspect_id of its evaluation)."""
    for s in intervals:
        end = s["t_end"] if s["t_end"] is not None else now_t
        if s["t_start"] <= body["t"] <= end and body.get("suspect_id") != s["id"]:
            return int(s["id"])
    return None


def attribute(
    bodies: Sequence[dict[str, Any]],
    intervals: Sequence[dict[str, Any]],
    limit_mm: float,
    now_u95_mm: float | None,
) -> str:
    """Whose a signal is (module docstring), looked at once the cell measured itself after the
    bodies that raised it: `bodies` the store's rows of those bodies (t, statement_u95_mm,
    suspect_id), `intervals` the suspect intervals, the plant's limit, and the U95 the cell
    states now (a knock shows there before its step is confirmed)."""
    for b in bodies:
        interval = suspect_of(b, intervals)
        if interval is not None:
            return f"maybe the gauge: measured inside suspect interval {interval}"
    stated = [b["statement_u95_mm"] for b in bodies] + [now_u95_mm]
    if any(u is None or u > limit_mm for u in stated):
        worst = max((u for u in stated if u is not None), default=None)
        said = "no U95 stated" if worst is None else f"U95 {worst:.3f} mm, limit {limit_mm:g} mm"
        return f"maybe the gauge: the cell could not vouch for its accuracy then ({said})"
    worst = max(float(u) for u in stated if u is not None)
    return (
        f"the process: the cell vouched for its accuracy over these bodies and after them (U95"
        f" at most {worst:.3f} mm, limit {limit_mm:g} mm)"
    )


def grouped_texts(signals: Sequence[tuple[Signal, str]], at_most: int = 3) -> list[str]:
    """The alarm texts of signals with their attributions: each alone, or, when more than
    `at_most` share an attribution (a knock moves every characteristic), one text for them."""
    by: dict[str, list[Signal]] = {}
    for sig, who in signals:
        by.setdefault(who, []).append(sig)
    out = []
    for who, sigs in by.items():
        if len(sigs) <= at_most:
            out += [s.text(who) for s in sigs]
            continue
        keys = ", ".join(s.key for s in sigs[:6]) + (", ..." if len(sigs) > 6 else "")
        out.append(f"SPC: {len(sigs)} characteristics signalled ({keys}): {who}")
    return out
