"""The body measured in-line (issue 48), judged as plants accept an in-line gauge, on seeds named
before they were looked at, geometric path, no offsets applied:

- correlation (`rvis experiment correlation`, app/sim/inspection.py): per seed, the commissioned
  simulated cell run for 120 windows (2 h: the warm-up and its first in-line recalibrations),
  then the values the service stored for the next `--bodies` bodies it measured in the cycle,
  against their truth (the simulated CMM): |mean difference| <= 0.05 mm for >= 90 % of the
  position characteristics and <= 0.10 mm for all, sd of the differences <= 0.05 mm, the stated
  U95 covering |in-line - truth| for >= 95 % of the values with its median <= 2.5x the RMS
  difference (per kind, and over all values as the issue words it), the decisions against the
  truth (>= 95 % of the values truly out by more than twice their U95 decided nonconforming,
  none truly in by more than their U95 decided nonconforming);
- type-1 study (`rvis experiment gauge`) on one master body, 50 repeats, T = the tolerance's
  width (1.0 mm for a position): Cg >= 1.33 for every position characteristic, Cgk >= 1.33 for
  >= 90 %;
- a sensor knock corrected in-line (`--knock sensor`): the re-evaluated values of its suspect
  bodies within 1.5x the steady RMS difference (the same seed's correlation without the knock);
- the robot's time per body and per feature in the simulation, against the anchors (Zeiss
  AIMax 1.8-3.0 s per position; NMS 200 features in 55 s: 0.275 s a feature).

    .venv/bin/python bench/body.py [--seeds 201,202,203,206] [--gauge-seed 204]
        [--knock-seed 205] [--bodies 50] [--json FILE]

A seed whose simulated cell fails its commissioning is another cell's story: said and skipped
(seed 201's calibration step fails; 206 was added when it did, before any body figure was seen).

Each figure is one run of a seeded simulation (a seed is a result: the medians are over the
seeds, the characteristics and the bodies); the CPU time of each run is printed beside it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import load_cell
from app.errors import RvisError
from app.sim.inspection import LineStudy, inspection_cell, run_correlation, run_gauge

AIMAX_S_PER_POSITION = (1.8, 3.0)
NMS_S_PER_FEATURE = 55.0 / 200.0


def correlation(seed: int, bodies: int, knock: str | None = None) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        doc = run_correlation(load_cell(None), seed, Path(tmp), LineStudy(bodies, 120, knock, 2.5))
        doc["cpu_s"] = time.process_time() - t0
        return doc


def gauge(seed: int, repeats: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.process_time()
        with inspection_cell(load_cell(None), seed, Path(tmp), 120) as cell:
            doc = run_gauge(cell, repeats)
        doc["cpu_s"] = time.process_time() - t0
        return doc


def correlation_verdicts(doc: dict[str, Any]) -> dict[str, Any]:
    s, d = doc["summary"], doc["decisions"]
    pos = s["position"]
    return {
        "mean<=0.05 (>=90%)": f"{s['position_mean_within_0_05']}/{pos}",
        "mean<=0.10 (all)": f"{s['position_mean_within_0_10']}/{pos}",
        "max |mean| mm": round(s["max_abs_mean_diff_mm"], 4),
        "max sd mm (<=0.05)": round(s["max_sd_diff_mm"], 4),
        "coverage (>=95%)": round(s["coverage"], 4),
        "U95/RMS all": round(s["u95_median_over_rms"], 2),
        "U95/RMS position": round(s["by_kind"]["position"]["u95_median_over_rms"], 2),
        "U95/RMS size": round(s["by_kind"]["size"]["u95_median_over_rms"], 2),
        "RMS position mm": round(s["by_kind"]["position"]["rms_diff_mm"], 4),
        "nok found/true": f"{d['nok_found']}/{d['nok_true']}",
        "nok false/ok true": f"{d['nok_false']}/{d['ok_true']}",
        "robot s/body": round(doc["line"]["robot_s_per_body"], 2),
        "robot s/feature": round(doc["line"]["robot_s_per_feature"], 3),
        "cpu s": round(doc["cpu_s"], 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="201,202,203,206")
    p.add_argument("--gauge-seed", type=int, default=204)
    p.add_argument("--knock-seed", type=int, default=205)
    p.add_argument("--bodies", type=int, default=50)
    p.add_argument("--repeats", type=int, default=50)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    out: dict[str, Any] = {"seeds": seeds, "correlation": {}, "gauge": None, "knock": None}
    for seed in seeds:
        try:
            doc = correlation(seed, args.bodies)
        except RvisError as exc:  # another cell's story: said and skipped
            print(f"correlation seed {seed}: skipped: {exc}", flush=True)
            out["correlation"][seed] = {"skipped": str(exc)}
            continue
        out["correlation"][seed] = doc
        print(f"correlation seed {seed}: {json.dumps(correlation_verdicts(doc))}", flush=True)
    g = gauge(args.gauge_seed, args.repeats)
    out["gauge"] = g
    print(f"type-1 seed {args.gauge_seed}: {json.dumps(g['summary'])}  cpu {g['cpu_s']:.1f} s")
    steady = correlation(args.knock_seed, args.bodies)
    knocked = correlation(args.knock_seed, args.bodies, "sensor")
    out["knock"] = {"steady": steady, "knocked": knocked}
    re = knocked.get("reevaluated", {})
    steady_rms = steady["summary"]["by_kind"]["position"]["rms_diff_mm"]
    after = re.get("rms_diff_after_mm")
    print(
        f"knock seed {args.knock_seed}: steady RMS {steady_rms:.4f} mm; re-evaluated"
        f" {re.get('bodies')} bodies ({re.get('values')} values, {re.get('not_reevaluated_bodies')}"
        f" left as measured): RMS {re.get('rms_diff_before_mm')} -> {after} mm, ratio to steady"
        f" {None if after is None else round(after / steady_rms, 2)} (<= 1.5)"
    )
    # the robot's time from every correlation run (the knock's steady one too: `--seeds ""`)
    ran = [d for d in [*out["correlation"].values(), steady] if "line" in d]
    per_body = [d["line"]["robot_s_per_body"] for d in ran]
    per_feature = [d["line"]["robot_s_per_feature"] for d in ran]
    med_f = statistics.median(per_feature)
    print(
        f"robot time: median {statistics.median(per_body):.1f} s a body,"
        f" {med_f:.3f} s a feature; AIMax {AIMAX_S_PER_POSITION[0]}-{AIMAX_S_PER_POSITION[1]} s"
        f" a position (ratio {med_f / AIMAX_S_PER_POSITION[0]:.2f}-"
        f"{med_f / AIMAX_S_PER_POSITION[1]:.2f}), NMS {NMS_S_PER_FEATURE:.3f} s a feature (ratio"
        f" {med_f / NMS_S_PER_FEATURE:.2f})"
    )
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
