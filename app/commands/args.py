"""Argument types shared by the subcommands: numbers checked where argparse reads them, so a
bad value is a one-line usage error (exit code 2) naming the option."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.errors import InputError


def int_at_least(lo: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {value}")
        return value

    return parse


def float_in(lo: float, hi: float, *, open_lo: bool = True) -> Callable[[str], float]:
    """A finite number in (lo, hi] (or [lo, hi] with open_lo=False)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
        low_ok = value > lo if open_lo else value >= lo
        if not (math.isfinite(value) and low_ok and value <= hi):
            bracket = "(" if open_lo else "["
            raise argparse.ArgumentTypeError(f"must lie in {bracket}{lo:g}, {hi:g}], got {text}")
        return value

    return parse


def sim_seed(seed: int | None, cfg: Any, commissioned: Path | None) -> int:
    """The simulated cell's seed: `--seed`, else the cell file's `[simulation] seed`. On a
    commissioned state directory (its cell file `commissioned`, which records the seed the
    simulated commissioning ran on) another seed is another cell: refused, one line."""
    own = int(cfg.simulation.seed)
    if seed is None or seed == own:
        return own
    if commissioned is not None:
        raise InputError(
            f"this directory was commissioned on the simulated cell of seed {own}; --seed {seed}"
            " is another cell (leave --seed out, or commission another directory)",
            file=commissioned,
            field="simulation.seed",
        )
    return seed


def say_waiting(line: str) -> None:
    """A simulation that must wait for another's device says so on stderr, at once."""
    import sys

    print(f"rvis: {line} (Ctrl-C to stop)", file=sys.stderr, flush=True)
