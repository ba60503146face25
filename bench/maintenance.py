"""Maintenance without re-commissioning (issue 41): each event and its procedure on the
simulated line, end to end (`rvis experiment maintenance`, app/sim/maintenance.py), on seeds
the procedures were not tuned on, and the issue's must-show per event:

- held within 3 windows of the event, every body from the event on in a suspect interval (one
  sphere replaced, `fixture:P2`: within 4, the spheres being measured in turn a slot a window,
  and the bodies from its first measurement after the event on: the spheres are the measuring
  chain's reference, not part of it, so the bodies before it were measured right);
- after the procedure, the end-to-end truth within 1.15x of before the event: the truth of
  the version the procedure handed over (the windows it was in force, until the service's
  first own recalibration after it) against the version before the event in the world without
  it at the same windows (`unchanged`: the world warms on during the procedure, which no
  procedure undoes), and against the windows before the event (`before`, reported); the
  line's 100 windows after the hand-over, the service's own recalibrations included, against
  the version before held in the world without the event (`line`, reported);
- the procedure's workspace validation within 0.8-1.25x of the truth after (and the truth
  at the validation's moment, reported);
- the procedure's robot time <= 1/3 of a whole commissioning's of the same cell;
- the service measuring again on the same state directory, its history kept.

    .venv/bin/python bench/maintenance.py [--seeds 21,22,23,24] [--events sensor,axis,fixture]
        [--axis 3] [--at-h 1.5] [--json FILE]
        [--knocks sensor,fixture,J1,J2,J3 [--after-windows 12]]  # issue 50: after each
        # hand-over a knock in the line's 4th window: flagged <= 3, named, within the limit <= 6

`--events fixture:P2`: the fixture event with only sphere P2 replaced; `fixture:frame`: the
fixture renewed moving the part frame against the robot's base (the spheres keep their places
in it: the tracker sees no change, the robot sees every sphere moved, and the procedure must
identify the part frame).

Prints a row per run and the totals; a seed whose simulated cell fails its commissioning is
another cell's story: said and skipped.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.config import load_cell
from app.errors import RvisError
from app.sim.maintenance import MaintenanceRun, run_maintenance


def one(
    event: str, seed: int, axis: int, at_h: float, knock: str = "", after_windows: int = 100
) -> dict[str, Any] | str:
    """One run; event "fixture:P2": only sphere P2 replaced; "fixture:frame": the renewal moves
    the part frame; `knock`: a knock in the 4th window after the hand-over."""
    kind, _, sphere = event.partition(":")
    frame = sphere == "frame"
    run = MaintenanceRun(
        kind, seed, axis, 3600.0 * at_h, sphere="" if frame else sphere, frame=frame,
        knock=knock, after_windows=after_windows,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        try:
            return run_maintenance(load_cell(None), Path(tmp), run)
        except RvisError as exc:
            return str(exc)


def changed_none(r: dict[str, Any]) -> bool:
    """The procedure handed over the version before with no chain parameter changed (a fixture
    renewed: the spheres' places measured again, the chain as it was): its truth after is the
    version before's in the same world, 1.000 x unchanged by construction."""
    return not (r.get("changed") or {}).get("identified")


def verdicts(r: dict[str, Any]) -> dict[str, bool]:
    det = r["detected_after_windows"]
    after, unchanged = r["truth_after_mm"], r["truth_unchanged_mm"]
    val = r["validation_after_mm"]
    # one sphere moved alone is seen when it is measured: the spheres in turn, a slot a window
    held_within = 4 if r.get("sphere") else 3
    return {
        "held<=3": det is not None and det <= held_within,
        "bodies": bool(r["bodies_after_event_suspect"]),
        "truth<=1.15x": after is not None and after <= 1.15 * unchanged,
        "val 0.8-1.25": val is not None and 0.8 <= val / after <= 1.25,
        "robot<=1/3": r["procedure_robot_s"] <= r["commissioning_robot_s"] / 3.0,
        "measuring": r["after_windows_measured"] > 0 and not r["after_held"],
        "history": bool(r["measurements_kept"] and r["suspect_intervals_kept"]),
    }


def totals(rows: list[dict[str, Any]]) -> None:
    """Each verdict's count over the runs; "truth<=1.15x" over the runs that changed a
    parameter, those that changed none (`changed_none`) counted apart."""
    print()
    keys = ["procedure", "held<=3", "bodies", "truth<=1.15x", "val 0.8-1.25", "robot<=1/3"]
    keys += ["measuring", "history"]
    for k in keys:
        pool = rows
        if k == "truth<=1.15x":
            pool = [r for r in rows if not changed_none(r)]
        n = sum(bool(r["verdicts"].get(k, k == "procedure")) for r in pool)
        extra = ""
        if len(pool) < len(rows):
            none = len(rows) - len(pool)
            extra = (
                f" of the runs that changed a parameter ({none} changed none: 1.000 by"
                " construction)"
            )
        print(f"{k:14} {n}/{len(pool)}{extra}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--seeds", default="21,22,23,24")
    p.add_argument("--events", default="sensor,axis,fixture")
    p.add_argument("--axis", type=int, default=3)
    p.add_argument("--at-h", type=float, default=1.5)
    p.add_argument("--json", type=Path)
    p.add_argument("--rows", type=Path, help="tabulate the rows of an earlier --json, run nothing")
    p.add_argument(
        "--knocks",
        help="after each hand-over a knock of each of these kinds (sensor,fixture,J1,J2,J3) in"
        " the line's 4th window: flagged <= 3 windows after it, named, within the limit <= 6",
    )
    p.add_argument("--after-windows", type=int, default=100)
    a = p.parse_args()
    if a.knocks:
        knocks(a)
        return
    if a.rows is not None:
        doc = json.loads(a.rows.read_text())
        totals(doc["rows"] if isinstance(doc, dict) else doc)
        return
    rows: list[dict[str, Any]] = []
    head = (
        f"{'event':10} {'seed':>4} {'held':>4} {'proc/comm s':>13} {'val/truth':>9} "
        f"{'truth mm: before unch. after':>29} {'after/unch':>10} {'line/unch':>9} verdicts"
    )
    print(head)
    t0 = time.monotonic()
    for event in a.events.split(","):
        for seed in (int(s) for s in a.seeds.split(",")):
            r = one(event, seed, a.axis, a.at_h)
            if isinstance(r, str):
                print(f"{event:10} {seed:>4} skipped: {r}", flush=True)
                continue
            if r["truth_after_mm"] is None or not r["procedure_passed"]:
                r["verdicts"] = {"procedure": False}
                rows.append(r)
                print(f"{event:10} {seed:>4} MISSED: the procedure did not hand back", flush=True)
                continue
            v = verdicts(r)
            r["verdicts"] = v
            rows.append(r)
            ratio = r["truth_after_mm"] / r["truth_unchanged_mm"]
            val = r["validation_after_mm"] / r["truth_after_mm"]
            robot = f"{r['procedure_robot_s']:.0f}/{r['commissioning_robot_s']:.0f}"
            truth = (
                f"{r['truth_before_mm']:.4f} {r['truth_unchanged_mm']:.4f}"
                f" {r['truth_after_mm']:.4f}"
            )
            line = r["truth_line_after_mm"] / r["truth_line_unchanged_mm"]
            failed = [k for k, ok in v.items() if not ok]
            said = "all" if not failed else "MISSED " + ", ".join(failed)
            print(
                f"{event:10} {seed:>4} {r['detected_after_windows'] or '-':>4} {robot:>13}"
                f" {val:9.2f} {truth:>29} {ratio:10.3f} {line:9.3f} {said}",
                flush=True,
            )
    totals(rows)
    print(f"{len(rows)} runs in {time.monotonic() - t0:.0f} s")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=str))


EXPECTED = {"sensor": "sensor", "fixture": "fixture", "J1": "fixture", "J2": "J2", "J3": "J3"}


def knocks(a: argparse.Namespace) -> None:
    """Knocks after a hand-over (issue 50): a row per event, seed and knock kind."""
    logging.getLogger("rvis").addHandler(logging.NullHandler())  # the rows, not the records
    logging.getLogger("rvis").propagate = False
    rows: list[dict[str, Any]] = []
    t0 = time.monotonic()
    print(f"{'event':10} {'seed':>4} {'knock':8} {'flagged':>7} {'named':8} {'within':>6} verdict")
    for event in a.events.split(","):
        for seed in (int(s) for s in a.seeds.split(",")):
            for knock in a.knocks.split(","):
                r = one(event, seed, a.axis, a.at_h, knock, a.after_windows)
                if isinstance(r, str) or not r["procedure_passed"]:
                    why = r if isinstance(r, str) else "the procedure failed"
                    print(f"{event:10} {seed:>4} {knock:8} skipped: {why}")
                    continue
                f, n = r["knock_flagged_after_windows"], r["knock_attribution"]
                w = r["knock_within_limit_after_windows"]
                ok = {
                    "flagged<=3": f is not None and f <= 3,
                    "named": n == EXPECTED.get(knock, knock),
                    "within<=6": w is not None and w <= 6,
                }
                r["knock_verdicts"] = ok
                rows.append(r)
                failed = [k for k, v in ok.items() if not v]
                said = "all" if not failed else "MISSED " + ", ".join(failed)
                fs, ws = ("-" if v is None else str(v) for v in (f, w))
                print(
                    f"{event:10} {seed:>4} {knock:8} {fs:>7} {n or '-':8} {ws:>6} {said}",
                    flush=True,
                )
    for k in ("flagged<=3", "named", "within<=6"):
        print(f"{k:12} {sum(r['knock_verdicts'][k] for r in rows)}/{len(rows)}")
    print(f"{len(rows)} runs in {time.monotonic() - t0:.0f} s")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
