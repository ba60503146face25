"""kill -9 of the in-line service at random moments, then a restart (issue 11, "must show").

Each round runs the service on in-process fakes (scaled clock, 8 measurements per window,
a recalibration every 4 measurements once the rolling set is complete, so parameters are
applied often) in a child process that prints every `done` it sends to the PLC with the number
of measurement rows committed at that moment; the parent kills the child with SIGKILL at a
random moment, then checks the state directory as a restart would find it: `PRAGMA
integrity_check` ok, at least every acknowledged measurement is in the database, and
`params/current.json` is one complete version of `params/history/`.

    nice -n 5 .venv/bin/python bench/line_crash.py [--rounds 50] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def child(state_dir: str) -> None:
    from app.config.line import RecalibSettings
    from fakes.devices import ClampCycle
    from tests.line.helpers import SCALE, line_settings, make_line

    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    ln = make_line(
        Path(state_dir),
        cycle=cycle,
        line=line_settings(window_s=32.0, slots_per_window=8),
        recalib=RecalibSettings(every_n=4),
    )
    ln.plc.on_done = lambda rows: print(f"ACK {rows}", flush=True)
    print("READY", flush=True)
    ln.service.run()


def check(state_dir: Path, acked: int) -> dict[str, object]:
    from app.formats.params import from_json
    from app.line.params_store import ParamsStore
    from app.line.store import Store

    store = Store(state_dir / "rvis.db")
    ok_db = store.integrity_ok()
    stored = sum(store.counts().values())
    versions = len(store.applied())
    store.close()
    params = ParamsStore(state_dir)
    current = json.loads(params.current_path.read_text(encoding="utf-8"))
    v = current["history_version"]
    same = current == json.loads(params.version_path(v).read_text(encoding="utf-8"))
    from_json(params.current_path)  # readable as a parameters file
    return {
        "integrity": ok_db,
        "acked": acked,
        "stored": stored,
        "params_ok": same,
        "version": v,
        "applied_rows": versions,
        "ok": ok_db and same and stored >= acked,
    }


def round_(state_dir: Path, rng_delay_s: float) -> dict[str, object]:
    proc = subprocess.Popen(
        [sys.executable, __file__, "--child", str(state_dir)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
        text=True,
        start_new_session=True,  # its own process group: with its identification workers
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "READY"
    acked = 0
    deadline = time.monotonic() + rng_delay_s
    while (left := deadline - time.monotonic()) > 0:
        ready, _, _ = select.select([proc.stdout], [], [], left)
        if ready:
            line = proc.stdout.readline()
            if line.startswith("ACK"):
                acked = max(acked, int(line.split()[1]))
    os.killpg(proc.pid, signal.SIGKILL)  # the service and its worker processes at once
    for line in proc.stdout:  # what it printed before it died was acknowledged too
        if line.startswith("ACK"):
            acked = max(acked, int(line.split()[1]))
    proc.wait()
    proc.stdout.close()
    return check(state_dir, acked)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--rounds", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-delay", type=float, default=3.0, help="latest kill after start [s]")
    p.add_argument("--state-dir", default="runs/line-crash")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        child(args.child)
        return 0
    import numpy as np

    rng = np.random.default_rng(args.seed)
    state = Path(args.state_dir)
    failures = 0
    for k in range(args.rounds):
        delay = float(rng.uniform(0.05, args.max_delay))
        r = round_(state, delay)
        bad = not r["ok"]
        failures += bad
        print(f"round {k + 1:3d}: killed after {delay:.2f} s: {r}", flush=True)
    print(
        f"{args.rounds - failures}/{args.rounds} rounds: every acknowledged measurement stored, "
        "database intact, parameters file a complete history version"
    )
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
