"""What a commissioning step returns: its checks (a figure against its limit) and results. Every
step module makes them with these; the journal keeps them (app/commission/journal.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Check:
    """One checked figure: its value, the limit it is held to (as text: "<= 0.1") and whether
    it passed; `unit` and `fmt` (the value's format, "" for 4 significant digits) for the
    report. A figure stated without a limit (`stated`) has the limit "" and counts as no
    check."""

    name: str
    value: float | int | str | bool
    limit: str
    ok: bool
    unit: str = ""
    fmt: str = ""

    @property
    def checked(self) -> bool:
        return self.limit != ""


#: figures in millimetres to a tenth of a micrometre, value and limit alike
MM = ".4f"
#: a ratio and its limit, and the two figures it is of, to 4 decimals
RATIO = ".4f"


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def at_most(
    name: str,
    value: float,
    limit: float,
    unit: str = "",
    *,
    ok: bool | None = None,
    fmt: str = "",
) -> Check:
    """value <= limit; `ok`: the verdict where another module decides it (the acceptance's
    figures, vision.acceptance), the limit then only shown; `fmt`: value and limit written
    at that precision (else the limit as set, the value to 4 significant digits)."""
    passed = bool(value <= limit) if ok is None else bool(ok)
    return Check(name, float(value), f"<= {limit:{fmt or 'g'}}{_unit(unit)}", passed, unit, fmt)


def at_least(name: str, value: float, limit: float, unit: str = "", *, fmt: str = "") -> Check:
    passed = bool(value >= limit)
    return Check(name, float(value), f">= {limit:{fmt or 'g'}}{_unit(unit)}", passed, unit, fmt)


def stated(name: str, value: float, unit: str = "", fmt: str = "") -> Check:
    """A figure the report states with the checks (its unit and precision) but holds to no
    limit (the workspace error's mean, largest, 95th percentile)."""
    return Check(name, float(value), "", True, unit, fmt)


def ratio_at_least(
    name: str, numerator: float, denominator: float, limit: float = 1.0, unit: str = ""
) -> Check:
    """numerator / denominator >= limit, stated as the ratio: its value and limit, and in the
    name the two figures it is of, all to 4 decimals ("O1, planned / random (0.1233 /
    0.1010)": 1.2210, ">= 1.0000")."""
    return _ratio(name, numerator, denominator, limit, unit, lower=True)


def ratio_at_most(
    name: str, numerator: float, denominator: float, limit: float = 1.0, unit: str = ""
) -> Check:
    """numerator / denominator <= limit, stated as `ratio_at_least` states it."""
    return _ratio(name, numerator, denominator, limit, unit, lower=False)


def _ratio(name: str, num: float, den: float, limit: float, unit: str, *, lower: bool) -> Check:
    """The ratio against its limit, a lower bound (`lower`) or an upper one."""
    value = num / den if den else math.inf
    of = f"{num:{RATIO}}{_unit(unit)} / {den:{RATIO}}{_unit(unit)}"
    op = ">=" if lower else "<="
    ok = value >= limit if lower else value <= limit
    return Check(f"{name} ({of})", float(value), f"{op} {limit:{RATIO}}", bool(ok), "", RATIO)


def within(name: str, value: float, lo: float, hi: float, unit: str = "") -> Check:
    """lo <= value <= hi, one check (its limit "15-90 %")."""
    return Check(name, float(value), f"{lo:g}-{hi:g}{_unit(unit)}", bool(lo <= value <= hi), unit)


def share_at_most(name: str, n: int, total: int, limit: float) -> Check:
    """n of total at most the fraction `limit`: the value in per cent, the counts in the name
    ("views rejected by vision (1 of 24)": 4.167 %, limit "<= 10 %")."""
    percent = 100.0 * n / total if total else 0.0
    return Check(
        f"{name} ({n} of {total})", percent, f"<= {100 * limit:g} %", n <= limit * total, "%"
    )


def count_at_least(name: str, n: int, total: int, limit: float) -> Check:
    """n of total at least `limit` (a count: "8 of 9", its limit ">= 9 of 9")."""
    need = math.ceil(limit - 1e-9)
    return Check(name, f"{n} of {total}", f">= {need} of {total}", bool(n >= limit))


def holds(name: str, ok: bool, detail: str = "") -> Check:
    return Check(name, detail or ("yes" if ok else "no"), "yes", bool(ok))


@dataclass
class StepResult:
    """What a step returns: its checks, the figures the report shows, the files it wrote
    (relative to the commission folder); `not_run`: why the step did not run here (a step
    that cannot run on this path, e.g. the acceptance's rendered sweeps on the simulated
    line's geometric path): journalled and reported as "not run", never as passed."""

    checks: list[Check] = field(default_factory=list)
    results: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)
    not_run: str = ""

    @property
    def passed(self) -> bool:
        return all(c.ok for c in self.checks)
