"""Is the U95 the service states true? (issue 38, ISO/TS 15530-4's check of uncertainty software)

Runs shifts of the simulated line (geometric path, warm-up on, a new commissioned cell) with a
knock of each kind at each hour given, on seeds the defaults were not tuned on, and compares each
window's stated U95 with the end-to-end true RMS error of the validation points in that window:

- coverage: share of windows with true RMS <= stated U95, over all windows, per shift (the
  worst), and over the windows the cell vouched for (not suspect);
- not inflated: median U95 / true RMS over steady windows (vouched, not within 10 windows of the
  knock);
- the plant's limit: of the windows whose true RMS is above `[service] accuracy_limit_mm`, the
  share that are suspect; of the suspect windows, the share whose true RMS is within the limit;
  the same by the 95th percentile of the window's points' true errors (the limit is one on a
  point's U95, VDA 5: a window of RMS 0.1 mm has points at 0.2 mm);
- the knock: windows to the flag (and any flag before it), attribution, windows until the true
  error is within the limit again and vouched for (and by the truth alone).

- where the suspect windows within the limit come from: a new cell's windows before the knock
  (stated from its commissioning's evidence), the knock's window and the two after it, the
  windows after; and how many of them have a true RMS above what an honest statement can vouch
  for (an honest U95 of a point is about 1.62x the RMS of a 3-D Gaussian error, 1.86x from one
  schedule cycle's residuals, 24: a window of RMS above limit / 1.86 cannot be vouched for);
- the same share for statements that knew each window's truth (clairvoyant): suspect exactly
  when the window's points' 95th percentile is above the limit, or when 1.62x (1.86x) its true
  RMS is: what the target can be on these shifts' true errors.

    python bench/accuracy_coverage.py [--seeds 21,22] [--hours-at 0.1,0.2,0.35] [--hours 1.5]
        [--workspace-positions N]

Prints a table per kind and hour and the totals; `--json FILE` keeps the rows (with each
shift's timeline: window, parameters version, true RMS, points' p95, stated U95, suspect).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import load_cell
from app.sim.shift import run_shift
from app.sim.shift_result import ShiftSettings
from calib.uncertainty import u95_mm

GROUP = {"sensor": "sensor", "fixture": "fixture", "joint": "J2"}
#: U95 / RMS of an honest statement: the norm's 95th percentile of a 3-D Gaussian error
#: (2.80 sigma = 1.62 RMS), and the bound from one schedule cycle's residuals (24) that happen
#: to be as large as the truth
PERFECT = u95_mm([1.0] * 100_000)
ONE_CYCLE = u95_mm([1.0] * 24)


def one(
    kind: str, at_h: float, seed: int, hours: float, positions: int | None, cell: str | None = None
) -> dict[str, Any]:
    cfg = load_cell(cell)
    if positions is not None:
        cfg = dataclasses.replace(
            cfg, commission=dataclasses.replace(cfg.commission, workspace_positions=positions)
        )
    with tempfile.TemporaryDirectory() as tmp:
        r = run_shift(cfg, Path(tmp) / "state", ShiftSettings(hours, at_h, kind), seed=seed)
    recs, k, limit = r.records, r.knock_window or 0, r.accuracy_limit_mm
    covered = [x.u95_mm is not None and x.rmse_mm <= x.u95_mm for x in recs]
    vouched = [x for x in recs if not x.suspect]
    steady = [x for x in vouched if x.window < k or x.window >= k + 10]
    bad = [x for x in recs if x.rmse_mm > limit]
    suspect = [x for x in recs if x.suspect]
    back = [x.window for x in recs if x.window >= k and x.rmse_mm <= limit and not x.suspect]
    back_true = [x.window for x in recs if x.window >= k and x.rmse_mm <= limit]
    return {
        "kind": kind,
        "at_h": at_h,
        "seed": seed,
        "windows": len(recs),
        "knock_window": k,
        "flagged_after": r.flagged_after,
        "flag_before_knock": bool([w for w in r.drift_alarm_windows if w < k]),
        "attributed": r.attribution,
        "attributed_right": r.attribution == GROUP[kind],
        "back_after": back[0] - k + 1 if back else None,
        "back_true_after": back_true[0] - k + 1 if back_true else None,
        "coverage": sum(covered) / len(recs),
        "coverage_vouched": (
            sum(x.rmse_mm <= (x.u95_mm or 0.0) for x in vouched) / len(vouched)
            if vouched
            else float("nan")
        ),
        "ratio_steady": (
            statistics.median((x.u95_mm or 0.0) / x.rmse_mm for x in steady)
            if steady
            else float("nan")
        ),
        "bad": len(bad),
        "bad_suspect": sum(x.suspect for x in bad),
        "suspect": len(suspect),
        "suspect_within": sum(x.rmse_mm <= limit for x in suspect),
        # the limit is one on a point's U95: a window whose points' 95th percentile is within it
        "bad_points": sum(x.p95_mm > limit for x in recs),
        "bad_points_suspect": sum(x.suspect for x in recs if x.p95_mm > limit),
        "suspect_within_points": sum(x.p95_mm <= limit for x in suspect),
        "mean_mm": statistics.fmean(x.rmse_mm for x in recs),
        "limit_mm": limit,
        # per validation point: the share of (window, point) within the window's stated U95
        "coverage_points": statistics.fmean(x.within_u95 or 0.0 for x in recs),
        # per window: [window, parameters version, true RMS, points' p95, stated U95, suspect]
        "timeline": [
            [
                x.window,
                x.version,
                round(x.rmse_mm, 5),
                round(x.p95_mm, 5),
                None if x.u95_mm is None else round(x.u95_mm, 5),
                x.suspect,
            ]
            for x in recs
        ],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="21,22")
    ap.add_argument("--hours-at", default="0.1,0.2,0.35")
    ap.add_argument("--hours", type=float, default=1.5)
    ap.add_argument("--kinds", default="sensor,fixture,joint")
    ap.add_argument(
        "--workspace-positions", type=int, help="[commission] workspace_positions (the cell's)"
    )
    ap.add_argument("--cell", help="a cell file (default: the embedded cell)")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    hours_at = [float(h) for h in a.hours_at.split(",")]
    rows = []
    t0 = time.perf_counter()
    print(
        "| kind | knock h | seed | flagged after | before? | attributed | back after |"
        " coverage | cov. vouched | U95/RMS steady | bad suspect | suspect within | mean mm |"
    )
    print("|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for kind in a.kinds.split(","):
        for at_h in hours_at:
            for seed in seeds:
                r = one(kind, at_h, seed, a.hours, a.workspace_positions, a.cell)
                rows.append(r)
                print(
                    f"| {kind} | {at_h:g} | {seed} | {r['flagged_after']} |"
                    f" {'yes' if r['flag_before_knock'] else 'no'} | {r['attributed']} |"
                    f" {r['back_after']} | {r['coverage']:.0%} | {r['coverage_vouched']:.0%} |"
                    f" {r['ratio_steady']:.2f} | {r['bad_suspect']}/{r['bad']} |"
                    f" {r['suspect_within']}/{r['suspect']} | {r['mean_mm']:.4f} |",
                    flush=True,
                )
    n_win = sum(r["windows"] for r in rows)
    cov = sum(r["coverage"] * r["windows"] for r in rows) / n_win
    bad = sum(r["bad"] for r in rows)
    sus = sum(r["suspect"] for r in rows)
    print()
    print(f"shifts {len(rows)}, windows {n_win}, {time.perf_counter() - t0:.0f} s")
    print(f"coverage (true RMS <= stated U95): {cov:.1%} of all windows;")
    print(f"  worst shift {min(r['coverage'] for r in rows):.1%}")
    print(f"  windows vouched for: {statistics.fmean(r['coverage_vouched'] for r in rows):.1%}")
    ratio = statistics.median(r["ratio_steady"] for r in rows)
    pts = statistics.fmean(r["coverage_points"] for r in rows)
    print(f"coverage per validation point (|true error| <= U95 of its window): {pts:.1%}")
    print(f"median U95 / true RMS in steady windows (median over shifts): {ratio:.2f}")
    bad_s = sum(r["bad_suspect"] for r in rows)
    within = sum(r["suspect_within"] for r in rows)
    print(f"windows above the limit that are suspect: {bad_s}/{bad}")
    print(f"suspect windows within the limit: {within}/{sus}")
    bad_p = sum(r["bad_points"] for r in rows)
    bad_ps = sum(r["bad_points_suspect"] for r in rows)
    within_p = sum(r["suspect_within_points"] for r in rows)
    print(
        "by the points' 95th percentile (the limit is a point's U95): windows above the limit"
        f" that are suspect {bad_ps}/{bad_p}; suspect windows within it {within_p}/{sus}"
    )
    flags = [r["flagged_after"] for r in rows]
    print(
        f"flagged within 3 windows: {sum(f is not None and f <= 3 for f in flags)}/{len(rows)};"
        f" flag before the knock: {sum(r['flag_before_knock'] for r in rows)};"
        f" attributed right: {sum(r['attributed_right'] for r in rows)}/{len(rows)};"
        f" back within the limit within 6 windows:"
        f" {sum(r['back_after'] is not None and r['back_after'] <= 6 for r in rows)}/{len(rows)}"
        f" (vouched for; by the truth alone"
        f" {sum(r['back_true_after'] is not None and r['back_true_after'] <= 6 for r in rows)})"
    )
    print(suspect_within_text(rows, limit=rows[0]["limit_mm"]))
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


def suspect_within_text(rows: list[dict[str, Any]], limit: float) -> str:
    """Where the suspect windows within the limit come from, and what the share would be for
    clairvoyant statements (module docstring)."""
    phases = {"before the knock": 0, "the knock and 2 after": 0, "later": 0}
    unvouchable = within = suspect = 0
    names = ("by the points' p95", f"{PERFECT:.2f}x RMS", f"{ONE_CYCLE:.2f}x RMS")
    seers = {name: [0, 0] for name in names}
    for r in rows:
        k = r["knock_window"]
        for w, _v, rms, p95, _u, sus in r["timeline"]:
            above = rms > limit
            for name, flag in zip(
                names, (p95 > limit, PERFECT * rms > limit, ONE_CYCLE * rms > limit), strict=True
            ):
                if flag or above:
                    seers[name][0] += 1
                    seers[name][1] += not above
            if not sus:
                continue
            suspect += 1
            if above:
                continue
            within += 1
            unvouchable += ONE_CYCLE * rms > limit
            phase = (
                "before the knock" if w < k else "the knock and 2 after" if w < k + 3 else "later"
            )
            phases[phase] += 1
    parts = ", ".join(f"{n} {name}" for name, n in phases.items())
    seen = "; ".join(f"{name} {n}/{m}" for name, (m, n) in seers.items())
    return (
        f"suspect windows within the limit: {within}/{suspect}: {parts}; {unvouchable} of them"
        f" with a true RMS above limit / {ONE_CYCLE:.2f} = {limit / ONE_CYCLE:.4f} mm\n"
        f"clairvoyant statements (suspect exactly when the window's points' p95, or a multiple of"
        f" its true RMS, is above the limit), suspect windows within the limit: {seen}"
    )


if __name__ == "__main__":
    main()
