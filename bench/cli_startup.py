"""Start-up time of the `rvis` command line (not run by the tests): `rvis --help` and
`rvis --version` as subprocesses, against a bare Python start-up measured in the same run, and
the commands that only read a state directory (`rvis status`, `rvis state check` on an empty
one: they say so and exit non-zero). Prints medians of repeated runs (targets: `rvis --help`
<= 0.25 s; `rvis status`, `rvis ctl`, `rvis state check|suspects` <= 0.15 s, issue 31).

    .venv/bin/python bench/cli_startup.py [--repeats 21]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time


def median_s(argv: list[str], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=21)
    args = parser.parse_args()
    rvis = [sys.executable, "-m", "app"]
    bare = median_s([sys.executable, "-c", "pass"], args.repeats)
    print(f"{'command':<34}{'median s':>10}{'vs python -c pass':>20}")
    print(f"{'python -c pass':<34}{bare:>10.3f}{1.0:>19.1f}x")
    empty = tempfile.mkdtemp()
    for extra in (
        ["--help"],
        ["--version"],
        ["identify", "--help"],
        ["status", "--state-dir", empty],
        ["state", "check", "--state-dir", empty],
    ):
        t = median_s([*rvis, *extra], args.repeats)
        name = "rvis " + " ".join(extra).replace(empty, "EMPTY")
        print(f"{name:<34}{t:>10.3f}{t / bare:>19.1f}x")


if __name__ == "__main__":
    main()
