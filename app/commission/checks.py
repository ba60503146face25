"""What a commissioning step returns: its checks (a figure against its limit) and results. Every
step module makes them with these; the journal keeps them (app/commission/journal.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Check:
    """One checked figure: its value, the limit it is held to (as text: "<= 0.1") and whether
    it passed; `unit` for the report."""

    name: str
    value: float | int | str | bool
    limit: str
    ok: bool
    unit: str = ""


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def at_most(
    name: str, value: float, limit: float, unit: str = "", *, ok: bool | None = None
) -> Check:
    """value <= limit; `ok`: the verdict where another module decides it (the acceptance's
    figures, vision.acceptance), the limit then only shown."""
    passed = bool(value <= limit) if ok is None else bool(ok)
    return Check(name, float(value), f"<= {limit:g}{_unit(unit)}", passed, unit)


def at_least(name: str, value: float, limit: float, unit: str = "") -> Check:
    return Check(name, float(value), f">= {limit:g}{_unit(unit)}", bool(value >= limit), unit)


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
    (relative to the commission folder)."""

    checks: list[Check] = field(default_factory=list)
    results: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.ok for c in self.checks)
