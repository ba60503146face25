"""The sensor's edge placement on certified bores, as an acceptance on a bore plate measures it:
the type-B allowance per side (`[sensor] edge_u_mm`) that a size's U95 carries for what stays
systematic in where the sensor puts a hole's or a slot's edge (app/inspect/values.py).

A plate with holes (6, 12, 20 mm) and a slot (8 x 20 mm) of certified sizes, 1.2 mm sheet, is
swept by the simulated rendered sensor (fakes.render_sheet: the camera's rows, the laser's
speckle, the bore's wall) 120 mm in front of the camera, tilted 0-15 degrees towards the laser
(as the line's views are, app.inspect.views) and rolled about its normal, each pose swept with
`--seeds` independent noise draws, and measured as the line measures a body's feature (the
profiles of app.sim.bodies.rendered_profiles, vision.features.measure_feature) with the sensor's
own model. Per size: the error against the certificate and the fit's own sd. The allowance, per
feature type (a round hole's, `[sensor] edge_u_mm`; a slot's, `edge_u_slot_mm`: its fit rests
on two straight sides and two end arcs, where a circle's averages its edge all round):

    u_edge = sqrt(max(0, mean(err^2) - mean(sd_fit^2)) / 2)

what the errors hold beyond the fit's own account of them, split over the two edges a size
spans (a size's U95 is 1.96 sqrt(sd_fit^2 + 2 u_edge^2)), or, where the errors' tails are
heavier than a normal distribution's (a slant edge's bias differs from view to view), the least
allowance with which the U95 covers 95 % of the certified sizes, whichever is larger: the
allowance; and the share of sizes covered with it, against the 0.002 mm the geometric sensor's
rule sets.

    .venv/bin/python bench/edge.py [--seeds 4] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.inspect.values import EDGE_U_MM, K95
from app.sim.bodies import rendered_profiles
from app.sim.cell import true_sensor_model
from fakes.render_sensor import default_true_sensor
from fakes.render_sheet import bench_commands, bench_pose
from vision.errors import FeatureRefused
from vision.features import measure_feature

F64 = NDArray[np.float64]
THICKNESS_MM = 1.2
FEATURES = (("hole", (6.0,)), ("hole", (12.0,)), ("hole", (20.0,)), ("slot", (8.0, 20.0)))
TILTS_DEG = (0.0, 5.0, 10.0, 15.0)
ROLLS_DEG = (0.0, 30.0, 75.0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    true = default_true_sensor()
    model = true_sensor_model(true)
    rows: list[dict[str, Any]] = []
    refused: dict[str, int] = {}
    t0 = time.process_time()
    for kind, size in FEATURES:
        cmds = bench_commands(true, 0.5 * max(size) + 3.0, 40)
        for tilt in TILTS_DEG:
            for roll in ROLLS_DEG:
                T = bench_pose(tilt, roll)
                R, t = T[:3, :3], T[:3, 3]
                for seed in range(args.seeds):
                    rng = np.random.default_rng([seed, int(tilt), int(roll), int(10 * size[0])])
                    profiles = rendered_profiles(
                        T, kind, size, THICKNESS_MM, true, model, rng, cmds
                    )
                    try:
                        fit = measure_feature(kind, profiles, t, R[:, 2], size, R[:, 0])
                    except FeatureRefused as exc:  # as the line refuses it: no number
                        why = str(exc).split(":")[0]
                        refused[why] = refused.get(why, 0) + 1
                        continue
                    for k, (got, sd) in enumerate(zip(fit.size_mm, fit.sd_size_mm, strict=True)):
                        names = ("D",) if kind == "hole" else ("W", "L")
                        rows.append(
                            {
                                "feature": f"{kind} {'x'.join(f'{s:g}' for s in size)}",
                                "size": names[k],
                                "tilt_deg": tilt,
                                "roll_deg": roll,
                                "error_mm": float(got - size[k]),
                                "sd_fit_mm": float(sd),
                            }
                        )
    cpu = time.process_time() - t0
    print(f"{len(rows)} sizes, sweeps refused: {refused or 'none'}, {cpu:.0f} s CPU")
    print("| size | n | mean error um | RMS error um | RMS sd_fit um |")
    print("|---|---|---|---|---|")
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(f"{r['feature']} {r['size']}", []).append(r)
    for label, g in groups.items():
        e, s = _errors(g)
        print(
            f"| {label} | {len(g)} | {1e3 * e.mean():+.1f} | {1e3 * math.sqrt(np.mean(e**2)):.1f}"
            f" | {1e3 * math.sqrt(np.mean(s**2)):.1f} |"
        )
    u_edge: dict[str, float] = {}
    print(
        "| feature type | sizes | u from the moments um | covered with it | u covering 95 % um"
        " | allowance um | covered with the rule's 2.0 um |"
    )
    print("|---|---|---|---|---|---|---|")
    for kind in ("hole", "slot"):
        e, s = _errors([r for r in rows if r["feature"].startswith(kind)])
        u_mom = math.sqrt(max(0.0, float(np.mean(e**2) - np.mean(s**2))) / 2.0)
        u_cov = _covering(e, s)
        u_edge[kind] = max(u_mom, u_cov)
        print(
            f"| {kind} | {len(e)} | {1e3 * u_mom:.1f} | {100 * _covered(e, s, u_mom):.1f} %"
            f" | {1e3 * u_cov:.1f} | **{1e3 * u_edge[kind]:.1f}** |"
            f" {100 * _covered(e, s, EDGE_U_MM):.1f} % |"
        )
    if args.json:
        doc = {"u_edge_mm": u_edge, "refused": refused, "rows": rows, "cpu_s": cpu}
        args.json.write_text(json.dumps(doc, indent=1))


def _errors(rows: list[dict[str, Any]]) -> tuple[F64, F64]:
    """The sizes' errors against their certificates and their fits' own sd [mm]."""
    err = np.array([float(r["error_mm"]) for r in rows])
    return err, np.array([float(r["sd_fit_mm"]) for r in rows])


def _covered(err: F64, sds: F64, u: float) -> float:
    """The share of sizes within their U95 with the allowance u per side."""
    return float(np.mean(np.abs(err) <= K95 * np.sqrt(sds**2 + 2.0 * u**2)))


def _covering(err: F64, sds: F64, share: float = 0.95) -> float:
    """The least allowance u per side [mm, to 0.1 um] with which `share` of the sizes are
    within their U95 (bisection: the share grows with u)."""
    lo, hi = 0.0, 0.05
    while hi - lo > 1e-7:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _covered(err, sds, mid) >= share else (mid, hi)
    return hi


if __name__ == "__main__":
    main()
