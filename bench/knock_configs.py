"""The knock campaign's configurations side by side (issue 28, item 3: the defaults chosen by
measurement): for each campaign folder written by `rvis experiment shift --knock all --seeds N
--knock-at-h ... --out DIR` (one per model x estimator), per knock kind over every hour and
seed, from each run's own timeline (`<kind>/at-<h>h/seed-<s>/shift.json`):

- the pre-knock level (median of the runs' `pre_knock_rmse_mm`) and the mean true error over
  the whole shift (warm-up, knock, recovery: what every body got);
- after the knock (the knock's window to the end of the shift): the mean true error, the worst
  window from the 3rd after the knock's (the target's median time to recover), and the share of
  its windows above 1.2x the run's own pre-knock level;
- the issue's recovery and interval figures (median / worst windows to recover, the episode
  recall over all runs), as the campaign report computes them.

The true error is the end-to-end one the simulated line computes (app/sim/truth.py: the point
measured as the line measures it).

    .venv/bin/python bench/knock_configs.py rigid-batch=DIR compliant-sequential=DIR ...
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

KINDS = ("sensor", "fixture", "joint")
RATIO = 1.2
SETTLE = 3  # windows after the knock's before "worst after": the target's median recovery


def _runs(folder: Path, kind: str) -> list[dict[str, Any]]:
    return [
        json.loads(p.read_text()) for p in sorted(folder.glob(f"{kind}/at-*h/seed-*/shift.json"))
    ]


def _row(name: str, kind: str, runs: list[dict[str, Any]]) -> str:
    means, after_means, after_max, above, recovered, pre = [], [], [], [], [], []
    bad = covered = 0
    for r in runs:
        timeline = r["summary"]["timeline"]
        k, level = int(r["knock_window"]), float(r["pre_knock_rmse_mm"])
        errors = [float(w["rmse_mm"]) for w in timeline]
        after = [float(w["rmse_mm"]) for w in timeline if int(w["window"]) >= k]
        means.append(statistics.fmean(errors))
        after_means.append(statistics.fmean(after))
        settled = [float(w["rmse_mm"]) for w in timeline if int(w["window"]) >= k + SETTLE]
        after_max.append(max(settled))
        above.append(sum(e > RATIO * level for e in after) / len(after))
        recovered.append(r["recovered_after_windows"])
        pre.append(level)
        score = r["suspect_score"] or {}
        bad += len(score.get("episode_bad", []))
        covered += len(set(score.get("episode_bad", [])) & set(score.get("covered", [])))
    back = sorted(x for x in recovered if x is not None)
    never = len(recovered) - len(back)
    worst = "never" if never else str(max(back))
    median = statistics.median([float("inf") if x is None else x for x in recovered])
    recall = f"{100 * covered / bad:.0f} %" if bad else "-"
    return (
        f"| {name} | {kind} | {len(runs)} | {statistics.median(pre):.4f} |"
        f" {statistics.fmean(means):.4f} | {statistics.fmean(after_means):.4f} |"
        f" {max(after_max):.4f} | {100 * statistics.fmean(above):.0f} % |"
        f" {median:g} / {worst} | {recall} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("campaigns", nargs="+", help="NAME=FOLDER of a knock campaign")
    args = ap.parse_args()
    print(
        "| configuration | knock | runs | pre-knock level (median) [mm] | mean true error over"
        " the shift [mm] | mean after the knock [mm] | worst window from the 3rd after the"
        " knock [mm] |"
        " windows after the knock above 1.2x their pre-knock level | windows to recover:"
        " median / worst | episode recall (all runs) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for item in args.campaigns:
        name, _, folder = item.partition("=")
        for kind in KINDS:
            runs = _runs(Path(folder), kind)
            if runs:
                print(_row(name, kind, runs))


if __name__ == "__main__":
    main()
