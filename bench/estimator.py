"""The one estimator (issue 50: calib/cellstate.py, app/line/jumps.py) judged on the simulated
line, on seeds named before any of their runs was looked at (JUDGING_SEEDS; the seeds the
estimator was developed on are TUNING_SEEDS, and the old tests' seeds 7, 14, 22-25, 100 are the
drift charts' tuning seeds, never cited as a reason here):

- knocks of each kind (the sensor mount, the spheres' frame, the J1, J2 and J3 zeros, one sphere
  alone) in a new cell's windows 1, 2, 4, 8 and 30 and at 2 h, each shift running one hour past
  its knock: flagged <= 3 windows after the knock, attributed to the group that moved (a J1
  zero is the part frame's rotation about the base's z axis in the model: "fixture"), the true
  RMS within the accuracy limit <= 6 windows after it (a sphere alone holds the cell for its
  procedure: flagged and named is its outcome). A sphere moved alone shows only when it is
  measured, one sphere of the four a slot: at one slot a window its first measurement after
  the knock comes 1-4 windows after it, so "<= 3" cannot hold for every knock time; the
  campaign says whether it was flagged at that measurement (`seen_after`);
- 8 h knock-free shifts: no alarm; their true RMS over the first hour <= 1.3x the robot's
  floor and over the 8 h <= 1.15x it (the floor: the RMS error of the validation points
  measured with exact parameters, the true robot's stops alone: app.sim.truth.robot_floor_mm);
- in every run, per point (the validation positions): the stated U95 covering >= 95 % of the
  true errors, the median U95 / true p95 <= 1.5; of the windows whose true p95 is above 1.2x the
  limit >= 98 % suspect, of the suspect ones <= 10 % with a true p95 below 0.8x the limit.

    .venv/bin/python bench/estimator.py [--seeds 301,302,303,304] [--kinds ...]
        [--windows 1,2,4,8,30] [--hours-at 2] [--jobs 2] [--json FILE] [--cell FILE]
        [--quiet-seeds 311,312,313,314]  # knock-free 8 h shifts on other seeds (QUIET_SEEDS)
        [--before-knock restart|rollback]  # the service restarted, or the engineer's rollback
        # and resume, three windows before each knock (knocks in window 4 or later; a rollback
        # needs an earlier version: --windows '' --hours-at 2)

Each row is one seeded shift in virtual time (a seed is a result); the figures per kind are
over the seeds and knock times, the CPU time of the whole campaign is printed.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

JUDGING_SEEDS = (301, 302, 303, 304)  # named before any run of them
# named 2026-11-30 before any run of them: knock-free 8 h shifts after jump_false_alarm went from
# 1e-4 to 1e-5 (seed 301's knock-free shift raised a step alarm at 1e-4: a tuning seed for it)
QUIET_SEEDS = (311, 312, 313, 314)
# named 2026-11-30 before any run of them: knock-free shifts judging the first hour after a
# change made on tuning seeds 61-68
FIRST_HOUR_SEEDS = (321, 322, 323, 324)
# named 2026-11-30 before any run of them: knock-free shifts judging the statement's unmodelled
# term pooled with the validation's degrees of freedom (found on 311's first hour: 311 a
# tuning seed of that change)
STATEMENT_SEEDS = (331, 332, 333, 334)
TUNING_SEEDS = (61, 62)  # the estimator's development seeds (61-68 for the first hour)
KINDS = ("sensor", "fixture", "J1", "J2", "J3", "sphere")
EXPECTED = {"sensor": "sensor", "fixture": "fixture", "J1": "fixture", "J2": "J2", "J3": "J3"}


CELL: str | None = None  # --cell: the cell file over the embedded cell (None: the embedded)


def _use_cell(path: str | None) -> None:
    global CELL
    CELL = path


BEFORE = "none"  # --before-knock: what happens three windows before each knock


def _use_before(before: str) -> None:
    global BEFORE
    BEFORE = before


def _setup(cell: str | None, before: str) -> None:
    _use_cell(cell)
    _use_before(before)


def shift(task: tuple[int, str, float, float]) -> dict[str, Any]:
    """One shift: (seed, knock kind, knock hour, hours) -> its figures (a knock-free shift's
    knock at its very end: no restart or rollback before it)."""
    from app.config import load_cell
    from app.sim.shift import run_shift
    from app.sim.shift_result import ShiftSettings

    seed, kind, knock_h, hours = task
    before = BEFORE if knock_h + 0.01 < hours else "none"
    logging.getLogger("rvis").addHandler(logging.NullHandler())  # the figures, not the records
    logging.getLogger("rvis").propagate = False
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        r = run_shift(
            load_cell(CELL),
            Path(tmp) / "state",
            ShiftSettings(hours=hours, knock_at_h=knock_h, knock=kind, before_knock=before),
            seed=seed,
        )
        cpu = time.process_time() - t0
    return figures(r.to_json(), kind, cpu)


def figures(doc: dict[str, Any], kind: str, cpu_s: float) -> dict[str, Any]:
    tl = doc["summary"]["timeline"]
    limit = float(doc["accuracy_limit_mm"])
    k = doc["knock_window"]
    covered = [r["within_u95"] for r in tl if r["within_u95"] is not None]
    ratio = [r["u95_mm"] / r["p95_mm"] for r in tl if r["u95_mm"] and r["p95_mm"] > 0]
    high = [r for r in tl if r["p95_mm"] > 1.2 * limit]
    suspect = [r for r in tl if r["suspect"]]
    low = [r for r in suspect if r["p95_mm"] < 0.8 * limit]
    floor = float(doc.get("floor_mm", math.nan))

    def over_floor(rows: list[dict[str, Any]]) -> float:
        return math.sqrt(statistics.fmean(r["rmse_mm"] ** 2 for r in rows)) / floor

    first_hour = [r for r in tl if r["t_h"] <= 1.0 and (k is None or r["window"] < k)]
    before = [r for r in tl if k is None or r["window"] < k]
    attributed = doc["attribution"]
    right = (
        attributed is not None and attributed.startswith("sphere:")
        if kind == "sphere"
        else attributed == EXPECTED.get(kind)
    )
    return {
        "seed": doc["seed"],
        "kind": kind,
        "knock_at_h": doc["settings"]["knock_at_h"],
        "knock_window": k,
        "flagged_after": doc["flagged_after_windows"],
        "attribution": attributed,
        "attributed_right": right,
        "within_limit_after": doc["within_limit_after_windows"],  # ShiftResult's
        "coverage": statistics.fmean(covered) if covered else math.nan,
        "u95_over_p95": statistics.median(ratio) if ratio else math.nan,
        "high": len(high),
        "high_suspect": sum(r["suspect"] for r in high),
        "suspect": len(suspect),
        "suspect_low": len(low),
        "alarms": doc["summary"]["alarms"],
        "alarm_windows_before": [w for w in doc["drift_alarm_windows"] if k is None or w < k],
        # a knock-free shift (its knock after the last window: no knock window) is all before
        "suspect_before": sum(r["suspect"] for r in tl if k is None or r["window"] < k),
        "limit_mm": limit,
        "floor_mm": floor,
        # the true RMS over the first hour and over the windows before the knock (a knock-free
        # shift: all of it) against the robot's floor
        "first_hour_over_floor": over_floor(first_hour) if first_hour else math.nan,
        "before_over_floor": over_floor(before) if before else math.nan,
        "held": bool(doc["summary"].get("maintenance")),
        # a sphere moved alone is seen only when it is measured: windows from the knock's to
        # the first that measured the sphere named (None: not named, or never measured)
        "seen_after": _seen_after(tl, k, attributed) if kind == "sphere" else None,
        "cpu_s": cpu_s,
    }


def _seen_after(tl: list[dict[str, Any]], k: int | None, attributed: str | None) -> int | None:
    if k is None or not attributed or not attributed.startswith("sphere:"):
        return None
    name = attributed.split(":", 1)[1]
    seen = [r["window"] for r in tl if r["window"] >= k and name in r.get("targets", ())]
    return seen[0] - k + 1 if seen else None


def table(rows: list[dict[str, Any]]) -> list[str]:
    out = [
        "| kind | shifts | flagged <= 3 | attributed right | within limit <= 6 | coverage >= 95 %"
        " | median U95/p95 (max) | high windows suspect | suspect windows low |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for kind in sorted({r["kind"] for r in rows}, key=KINDS.index):
        rs = [r for r in rows if r["kind"] == kind]
        n = len(rs)
        flag = sum(r["flagged_after"] is not None and r["flagged_after"] <= 3 for r in rs)
        attr = sum(r["attributed_right"] for r in rs)
        back = [r for r in rs if not r["held"]]
        ok_back = sum(
            r["within_limit_after"] is not None and r["within_limit_after"] <= 6 for r in back
        )
        cov = sum(r["coverage"] >= 0.95 for r in rs)
        ratios = [r["u95_over_p95"] for r in rs]
        hi = sum(r["high"] for r in rs)
        hs = sum(r["high_suspect"] for r in rs)
        su = sum(r["suspect"] for r in rs)
        lo = sum(r["suspect_low"] for r in rs)
        out.append(
            f"| {kind} | {n} | {flag}/{n} | {attr}/{n} | {ok_back}/{len(back)} | {cov}/{n}"
            f" | {statistics.median(ratios):.2f} ({max(ratios):.2f}) | {hs}/{hi}"
            f" | {lo}/{su} |"
        )
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default=",".join(map(str, JUDGING_SEEDS)))
    p.add_argument("--kinds", default=",".join(KINDS))
    p.add_argument("--windows", default="1,2,4,8,30", help="knock in these windows")
    p.add_argument("--hours-at", default="2", help="and at these hours")
    p.add_argument("--quiet-hours", type=float, default=8.0, help="knock-free shift (0: none)")
    p.add_argument("--quiet-seeds", help="the knock-free shifts' seeds (default: --seeds)")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--json", type=Path)
    p.add_argument("--cell", help="a cell file over the embedded cell (its settings)")
    p.add_argument(
        "--before-knock",
        choices=("none", "restart", "rollback"),
        default="none",
        help="three windows before each knock (app.sim.shift.BEFORE_KNOCK): knocks in window 4"
        " or later; a rollback after the first in-line recalibration (--windows '')",
    )
    a = p.parse_args()
    _use_cell(a.cell)
    _use_before(a.before_knock)
    seeds = [int(s) for s in a.seeds.split(",")]
    period_h = 60.0 / 3600.0  # [simline] period_s of the embedded cell
    times = [(int(w) - 1) * period_h for w in a.windows.split(",") if w]
    times += [float(h) for h in a.hours_at.split(",") if h]
    tasks = [(s, k, t, round(t + 1.0, 6)) for s in seeds for k in a.kinds.split(",") for t in times]
    if a.quiet_hours > 0:  # the knock at the shift's very end: a knock-free shift before it
        quiet_seeds = [int(s) for s in (a.quiet_seeds or a.seeds).split(",")]
        tasks += [(s, "sensor", a.quiet_hours - 0.001, a.quiet_hours) for s in quiet_seeds]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs, initializer=_setup, initargs=(a.cell, a.before_knock)) as pool:
        rows = list(pool.map(shift, tasks))
    wall = time.perf_counter() - t0
    knocks = [r for r, t in zip(rows, tasks, strict=True) if t[3] != a.quiet_hours]
    quiet = [r for r, t in zip(rows, tasks, strict=True) if t[3] == a.quiet_hours]
    before = "" if a.before_knock == "none" else f", a {a.before_knock} 3 windows before each knock"
    print(
        f"seeds {seeds}; {len(knocks)} knocked shifts{before}, {len(quiet)} knock-free;"
        f" wall {wall:.0f} s"
    )
    print("\n".join(table(knocks)))
    for r in quiet:
        print(
            f"knock-free {a.quiet_hours:g} h, seed {r['seed']}: windows with a drift or step alarm"
            f" {len(r['alarm_windows_before'])}, suspect windows {r['suspect_before']},"
            f" coverage {r['coverage']:.3f},"
            f" U95/p95 {r['u95_over_p95']:.2f}, limit {r['limit_mm']:.3f} mm;"
            f" robot's floor {r['floor_mm']:.4f} mm, true RMS / floor: first hour"
            f" {r['first_hour_over_floor']:.2f} (<= 1.3), {a.quiet_hours:g} h"
            f" {r['before_over_floor']:.2f} (<= 1.15)"
        )
    spheres = [r for r in knocks if r["kind"] == "sphere"]
    if spheres:
        first = sum(
            r["seen_after"] is not None and r["flagged_after"] == r["seen_after"] for r in spheres
        )
        print(
            f"sphere alone: flagged at the moved sphere's first measurement after the knock in"
            f" {first} of {len(spheres)} (one sphere of the four in each slot: the knock is"
            " seen no sooner)"
        )
    misses = [r for r in knocks if not r["attributed_right"] or (r["flagged_after"] or 99) > 3]
    for r in misses:
        seen = (
            ""
            if r["seen_after"] is None
            else f", its sphere first measured after {r['seen_after']}"
        )
        print(
            f"miss: seed {r['seed']} {r['kind']} at window {r['knock_window']}: flagged after"
            f" {r['flagged_after']}, attributed {r['attribution']}{seen}"
        )
    if a.json:
        a.json.write_text(json.dumps({"knocks": knocks, "quiet": quiet}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
