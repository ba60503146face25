"""SPC of the bodies' characteristics that knows gauge from process (issue 49 item 5).

An individuals chart per characteristic, as plants run them: the centre and sigma from the
first `BASELINE_N` values (sigma from the average moving range / 1.128), then the Western
Electric run rules on each new value:

    rule 1  one value beyond 3 sigma
    rule 5  2 of 3 values in a row beyond 2 sigma on the same side
    rule 4  8 values in a row on the same side of the centre

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
from typing import Any

BASELINE_N = 20
#: the first bodies a chart is replayed from hold its baseline (a feature not measured in a few
#: of them included): the service's charts at a start, the operator's view of their limits
BASELINE_BODIES = 2 * BASELINE_N
#: the control limits: centre +- this many sigma (rule 1)
LIMIT_SIGMA = 3.0
QUIET_N = 8
#: the values a chart's run rules look back over
RECENT_N = 8
RULES = {
    1: "a value beyond 3 sigma",
    5: "2 of 3 values beyond 2 sigma on one side",
    4: "8 values in a row on one side of the centre",
}


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
    """One characteristic's chart (module docstring)."""

    key: str
    baseline: list[float] = field(default_factory=list)
    centre: float = math.nan
    sigma: float = math.nan
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
        n = {1: 1, 5: 3, 4: 8}[rule]
        bodies = [b for _, b in list(self.recent)[-n:]]
        return Signal(self.key, rule, bodies, self.centre, self.sigma)

    @property
    def limits_mm(self) -> tuple[float, float]:
        """The lower and upper control limits (nan before the baseline is complete)."""
        return self.centre - LIMIT_SIGMA * self.sigma, self.centre + LIMIT_SIGMA * self.sigma

    def _limits(self) -> None:
        b = self.baseline
        self.centre = sum(b) / len(b)
        mr = [abs(y - x) for x, y in itertools.pairwise(b)]
        self.sigma = max(sum(mr) / len(mr) / 1.128, 1e-6)

    def _rule(self) -> int | None:
        z = [(v - self.centre) / self.sigma for v, _ in self.recent]
        if abs(z[-1]) > LIMIT_SIGMA:
            return 1
        last3 = z[-3:]
        for side in (1.0, -1.0):
            if len(last3) == 3 and sum(side * x > 2.0 for x in last3) >= 2:
                return 5
        if len(z) == 8 and (all(x > 0 for x in z) or all(x < 0 for x in z)):
            return 4
        return None


def chart_key(value: dict[str, Any]) -> str:
    """The chart of a stored value (feature, characteristic): "H01.X"."""
    return f"{value['feature']}.{value['characteristic']}"


def add_values(
    charts: dict[str, IndividualsChart], body: Any, values: Iterable[dict[str, Any]]
) -> list[Signal]:
    """A body's stored values (feature, characteristic, measured_mm) each into its chart (made
    when it is the first), those not measured left out; the signals they raise."""
    signals = []
    for v in values:
        if v["measured_mm"] is None:
            continue
        key = chart_key(v)
        signal = charts.setdefault(key, IndividualsChart(key)).add(float(v["measured_mm"]), body)
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
