"""kill -9 campaign of the service as the plant runs it (issue 19, "must show"): `rvis run --sim
--geometric` as its own process on a fast simulated clock, killed with SIGKILL (its whole process
group, identification workers included) at random moments, half of them at the worst ones (just
as a recalibration starts, or as a calibration is decided and applied), and restarted, N times.

After every kill the state directory is checked as the restart will find it: `PRAGMA
integrity_check`, every measurement the service announced (its `measurement` log line comes after
the commit, before the PLC's `done`) still stored, no torn file (`current.json` and every
history version parse, `current.json` is one history version), and a temporary file of a write
cut short by the kill gone after the restart. At the end an
uninterrupted service on the same seed runs as many windows, and the calibrations attempted
per measurement are compared: restarts must not cost recalibrations.

    nice -n 5 .venv/bin/python bench/ops_campaign.py [--kills 200] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import queue
import sqlite3
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.line.statedir import version_name
from tests.ops.conftest import ServiceProcess, count, rvis

# the service's defaults (rolling set 24, a recalibration every 24 measurements), one window
# every 0.2 s (60 s clamp cycles at x300)
CELL = "[simline]\nscale = 300.0\n"
TRIGGERS = {"start": "recalibration_started", "apply": "calibration"}


def inspect(state: Path, announced: set[int]) -> dict[str, Any]:
    """What a restart finds: integrity, lost announced rows, torn or temporary files."""
    db = state / "rvis.db"
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        integrity = con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        ids = {int(r[0]) for r in con.execute("SELECT id FROM measurements")}
    finally:
        con.close()
    torn: list[str] = []
    temporary = [str(p) for p in state.rglob(".*.tmp")]  # a kill between write and rename
    history = state / "params" / "history"
    docs = {}
    for f in history.glob("*.json"):
        try:
            docs[f.name] = json.loads(f.read_text(encoding="utf-8"))
        except ValueError:
            torn.append(str(f))
    try:
        current = json.loads((state / "params" / "current.json").read_text(encoding="utf-8"))
        if docs.get(version_name(current["history_version"])) != current:
            torn.append("current.json is no history version")
    except (OSError, ValueError, KeyError) as exc:
        torn.append(f"current.json: {exc}")
    return {
        "integrity": integrity,
        "lost": len(announced - ids),
        "torn": torn,
        "temporary": temporary,
        "rows": len(ids),
    }


def life(state: Path, cell: Path, how: str, delay_s: float) -> tuple[set[int], str, bool]:
    """One life of the service: start, then SIGKILL after `delay_s` (how == "random") or just
    after its first `TRIGGERS[how]` log line; the measurement ids it announced, when it died,
    and whether it had started (its state directory opened: stale temporary files removed)."""
    svc = ServiceProcess(state, cell)
    trigger = TRIGGERS.get(how)
    announced: set[int] = set()
    started = False
    deadline = time.monotonic() + (30.0 if trigger else delay_s)
    when = f"after {delay_s:.2f} s" if trigger is None else f"no {trigger} in 30 s"
    while (left := deadline - time.monotonic()) > 0:
        try:
            line = svc.lines.get(timeout=left)
        except queue.Empty:
            break
        event = line.get("event")
        started = started or event == "started"
        if event == "measurement":
            announced.add(int(line["data"]["id"]))
        if trigger is not None and event == trigger:
            when = f"at {event}"
            break
    svc.kill9()
    while True:  # what it printed before it died was announced too
        try:
            line = svc.lines.get_nowait()
        except queue.Empty:
            return announced, when, started
        if line.get("event") == "measurement":
            announced.add(int(line["data"]["id"]))


def attempts(db: Path) -> tuple[int, int]:
    """(calibrations attempted, measurements stored)."""
    return (
        count(db, "SELECT COUNT(*) FROM calibrations"),
        count(db, "SELECT COUNT(*) FROM measurements WHERE status = 'ok'"),
    )


def uninterrupted(root: Path, cell: Path, windows: int) -> tuple[int, int, float]:
    state = root / "uninterrupted"
    t0 = time.monotonic()
    out = rvis(
        "run",
        "--sim",
        "--geometric",
        "--cell",
        str(cell),
        "--state-dir",
        str(state),
        "--windows",
        str(windows),
        "--json",
        timeout_s=3600.0,
    )
    if out.returncode != 0:
        raise SystemExit(f"the uninterrupted run failed: {out.stderr.strip()}")
    return (*attempts(state / "rvis.db"), time.monotonic() - t0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kills", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-delay", type=float, default=6.0, help="latest random kill [s]")
    args = p.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    t_start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        cell = root / "cell.toml"
        cell.write_text(CELL, encoding="utf-8")
        state = root / "state"
        announced: set[int] = set()
        bad = {"integrity": 0, "lost": 0, "torn": 0, "temporary": 0, "temporary_kept": 0}
        left: list[str] = []  # temporary files of the previous kill: the restart removes them
        kinds = {"random": 0, "start": 0, "apply": 0}
        for k in range(args.kills):
            how = str(rng.choice(["random", "random", "start", "apply"]))
            got, when, started = life(state, cell, how, float(rng.uniform(0.3, args.max_delay)))
            announced |= got
            if started:
                bad["temporary_kept"] += sum(Path(f).exists() for f in left)
            kinds[how] += 1
            found = inspect(state, announced)
            bad["integrity"] += not found["integrity"]
            bad["lost"] += found["lost"]
            bad["torn"] += len(found["torn"])
            bad["temporary"] += len(set(found["temporary"]) - set(left))
            left = found["temporary"]
            print(
                f"kill {k + 1:3d} {how:<6} {when:<28} rows {found['rows']:5d}"
                f" lost {found['lost']} torn {found['torn'] or 0}"
                f" temporary {len(left)}",
                flush=True,
            )
        # the last life must come up and measure
        svc = ServiceProcess(state, cell)
        try:
            svc.wait_ready()
            bad["temporary_kept"] += sum(Path(f).exists() for f in left)
        finally:
            final_code = svc.stop()
        db = state / "rvis.db"
        windows = count(db, "SELECT COALESCE(MAX(window), 0) FROM measurements")
        cal_c, n_c = attempts(db)
        cal_u, n_u, t_u = uninterrupted(root, cell, windows)
    print()
    print(
        f"kills {args.kills} ({kinds['random']} at random moments, {kinds['start']} as a"
        f" recalibration started, {kinds['apply']} as a calibration was decided/applied)"
    )
    print(f"restarts {args.kills + 1}, the last stopped cleanly with exit {final_code}")
    print()
    print("| figure | killed and restarted | uninterrupted, same seed |")
    print("|---|---:|---:|")
    print(f"| integrity failures | {bad['integrity']} | - |")
    print(f"| torn files (a partial file under its name) | {bad['torn']} | - |")
    print(
        f"| temporary files left by a kill / still there after the restart"
        f" | {bad['temporary']} / {bad['temporary_kept']} | - |"
    )
    print(f"| announced (committed) measurements lost | {bad['lost']} of {len(announced)} | - |")
    print(f"| measurements stored (ok) | {n_c} | {n_u} |")
    print(f"| calibrations attempted | {cal_c} | {cal_u} |")
    print(
        f"| attempted per 100 measurements | {100 * cal_c / max(n_c, 1):.2f}"
        f" | {100 * cal_u / max(n_u, 1):.2f} |"
    )
    print()
    print(f"campaign {time.monotonic() - t_start:.0f} s wall (uninterrupted run {t_u:.0f} s)")
    ok = not (bad["integrity"] or bad["lost"] or bad["torn"] or bad["temporary_kept"])
    ok = ok and final_code == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
