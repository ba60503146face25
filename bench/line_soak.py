"""Soak of the in-line service (issue 11): N windows on in-process fakes (geometric sensor,
scaled clock, a recalibration every 24 measurements) while the resident memory, the open file
descriptors and the threads of the process are sampled; they must stay flat.

    nice -n 5 .venv/bin/python bench/line_soak.py [--windows 1000]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def rss_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def main(argv: list[str] | None = None) -> int:
    from app.config.line import RecalibSettings
    from fakes.devices import ClampCycle
    from tests.line.helpers import line_settings, make_line

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--windows", type=int, default=1000)
    p.add_argument("--every", type=int, default=100)
    p.add_argument("--scale", type=float, default=0.01)
    args = p.parse_args(argv)
    import tests.line.helpers as h

    h.SCALE = args.scale
    cycle = ClampCycle(period_s=12.0, window_s=8.0, beat_s=0.5, time_scale=args.scale)
    with tempfile.TemporaryDirectory() as tmp:
        ln = make_line(
            Path(tmp),
            cycle=cycle,
            line=line_settings(window_s=8.0),
            recalib=RecalibSettings(every_n=24),
        )
        ln.start()
        print("windows  rss_MiB  fds  threads  measured  overruns  params_version")
        try:
            for k in range(1, args.windows + 1):
                ln.wait(lambda e: e["event"] == "window", 30.0)
                if k % args.every == 0 or k == 1:
                    st = ln.service.status()
                    fds = len(os.listdir("/proc/self/fd"))
                    print(
                        f"{k:7d}  {rss_kib() / 1024:7.1f}  {fds:3d}  {threading.active_count():7d}"
                        f"  {st['measurements']['ok']:8d}  {st['counters']['overruns']:8d}"
                        f"  {st['params_version']:14d}",
                        flush=True,
                    )
        finally:
            ln.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
