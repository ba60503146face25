"""Argument types shared by the subcommands: numbers checked where argparse reads them, so a
bad value is a one-line usage error (exit code 2) naming the option."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


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
