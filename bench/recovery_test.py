"""Monte Carlo of the recovery test that ends a step's suspect interval (app.line.step.
recovery_test), the old one-sided F test ("not shown higher" read as "back") against the
equivalence test with its looks sharing one confidence, on the service's defaults ([service]
recovery_confidence 0.95, recovery_min_measurements 6, recovery_margin 0.25,
recovery_tolerance_mm 0.02).

Each run: `n_before` residual norms of the schedule cycle before the step (3-D normal, RMS
`LEVEL_MM`), then, with the correction in force, `per_window` norms per window for up to 12
windows at RMS `ratio` x LEVEL_MM; the test is made after every window (the old test decides
at every window from 6 measurements on; the new one looks at 6, 12, 24, 48 ... of them) and
the run counts as "back" when any window says so. With no measurement before
the step the new test compares with the true level as its reference (`reference_mm`); the old
one cannot decide. At LEVEL_MM 0.06 mm the tolerated level is max(1.25 x 0.06, 0.06 + 0.02) =
0.08 mm, a ratio of 4/3: "back" is right at ratios 1.0 and 1.25 (the share is the power) and
false from 1.5 on (the share is the false "back" rate); at 4/3 exactly it is the level the
test is held to (at most 5 %).

The verdicts are computed vectorised with the quantiles of the service's rules (the F and
chi-square quantiles depend on the counts and the look only); the first `CHECK` runs of every
cell are decided again by app.line.step.recovery_test itself and must agree (else it exits 1).

    .venv/bin/python bench/recovery_test.py [--runs 2000] [--seed 0] [--per-window 1]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from scipy.stats import chi2
from scipy.stats import f as f_dist

from app.config.line import RecalibSettings
from app.line.step import look_level, recovery_under

LEVEL_MM = 0.06  # RMS of the held-out residual norms before the step
RATIOS = (1.0, 1.25, 4 / 3, 1.5, 2.0, 3.0)  # true RMS after / before
N_BEFORE = (0, 6, 12, 24)
WINDOWS = 12
CHECK = 40  # runs per cell decided again by app.line.step.recovery_test


def _norms(rng: np.random.Generator, rms: float, shape: tuple[int, int]) -> np.ndarray:
    """Norms of 3-D normal vectors whose RMS norm is `rms` [mm], shape (runs, n)."""
    return np.linalg.norm(rng.normal(0.0, rms / np.sqrt(3.0), (*shape, 3)), axis=2)


def _old(
    before: np.ndarray, after: np.ndarray, per: int, conf: float, min_after: int
) -> np.ndarray:
    """The old rule, vectorised: back at a window when (RMS after / RMS before)^2 is not above
    the F(3 n_after, 3 n_before) quantile at `conf` and at least `min_after` were measured."""
    runs, n_b = before.shape[0], before.shape[1]
    back = np.zeros(runs, dtype=bool)
    if n_b == 0:
        return back  # "undetermined" for ever
    ms_b = np.mean(before**2, axis=1)
    for w in range(1, WINDOWS + 1):
        n = w * per
        if n < min_after:
            continue
        ratio = np.mean(after[:, :n] ** 2, axis=1) / ms_b
        back |= ratio <= f_dist.ppf(conf, 3 * n, 3 * n_b)
    return back


def _new(
    before: np.ndarray, after: np.ndarray, per: int, r: RecalibSettings
) -> tuple[np.ndarray, np.ndarray]:
    """The equivalence test, vectorised (app.line.step.recovery_test's rule): back at look k
    when the upper bound of the RMS after at level alpha / (k (k + 1)) is within the tolerated
    level. Returns (back at any look, the first window it was back, 0 when never)."""
    runs, n_b = before.shape[0], before.shape[1]
    alpha = 1.0 - r.recovery_confidence
    level = np.sqrt(np.mean(before**2, axis=1)) if n_b else np.full(runs, LEVEL_MM)
    tolerated = np.maximum((1.0 + r.recovery_margin) * level, level + r.recovery_tolerance_mm)
    first = np.zeros(runs, dtype=int)
    look, last_n = 0, 0
    for w in range(1, WINDOWS + 1):
        n = w * per
        if n < max(r.recovery_min_measurements, 2 * last_n):
            continue  # a look at twice as many measurements as the last one
        look, last_n = look + 1, n
        a = look_level(alpha, look)
        ratio = np.mean(after[:, :n] ** 2, axis=1) / level**2
        # the upper bound's factor on the ratio: F (with a level before) or chi-square
        q = float(f_dist.ppf(1.0 - a, 3 * n_b, 3 * n)) if n_b else 3 * n / float(chi2.ppf(a, 3 * n))
        upper = level * np.sqrt(ratio * q)
        first[(first == 0) & (upper <= tolerated)] = w
    return first > 0, first


def _check(
    before: np.ndarray, after: np.ndarray, per: int, r: RecalibSettings, first: np.ndarray
) -> int:
    """Runs whose first "back" window differs between the vectorised rule and recovery_test."""
    wrong = 0
    for i in range(min(CHECK, before.shape[0])):
        got, looks, last_n = 0, 0, 0
        for w in range(1, WINDOWS + 1):
            test = recovery_under(
                r,
                before[i],
                after[i, : w * per],
                looks=looks,
                last_look_n=last_n,
                reference_mm=None if before.shape[1] else LEVEL_MM,
            )
            if test.look:
                looks, last_n = test.look, test.n_after
            if test.verdict == "back":
                got = w
                break
        wrong += got != first[i]
    return wrong


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-window", type=int, default=1, help="residuals per window")
    args = ap.parse_args(argv)
    r, per = RecalibSettings(), args.per_window
    t0 = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    rows, wrong = [], 0
    for ratio in RATIOS:
        cells = []
        for n_b in N_BEFORE:
            before = _norms(rng, LEVEL_MM, (args.runs, n_b))
            after = _norms(rng, ratio * LEVEL_MM, (args.runs, WINDOWS * per))
            old = _old(before, after, per, r.recovery_confidence, r.recovery_min_measurements)
            new, first = _new(before, after, per, r)
            wrong += _check(before, after, per, r, first)
            median = f"{np.median(first[new]):.0f}" if new.any() else "-"
            cells.append(f"{old.mean():5.1%} / {new.mean():5.1%} ({median})")
        rows.append(f"| {ratio:.3g} | " + " | ".join(cells) + " |")
    tolerated = max((1 + r.recovery_margin) * LEVEL_MM, LEVEL_MM + r.recovery_tolerance_mm)
    print(
        f"recovery test, {args.runs} runs per cell, seed {args.seed}, {per} residual(s) per"
        f" window, {WINDOWS} windows, level before {LEVEL_MM} mm, tolerated {tolerated:.3f} mm"
        f" (ratio {tolerated / LEVEL_MM:.3f})"
    )
    print("share of runs declared back at any look: old / new (new: median window of back)\n")
    print("| true RMS ratio after / before | " + " | ".join(f"{n} before" for n in N_BEFORE) + " |")
    print("|---|" + "---:|" * len(N_BEFORE))
    print("\n".join(rows))
    checked = CHECK * len(RATIOS) * len(N_BEFORE)
    print(
        f"\n{checked} runs decided again by app.line.step.recovery_test: {wrong} disagree;"
        f" {time.perf_counter() - t0:.1f} s"
    )
    return 1 if wrong else 0


if __name__ == "__main__":
    raise SystemExit(main())
