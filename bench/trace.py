"""The wire trace's cost: one request/reply round trip through each protocol back end with the
untraced drivers (the package before the trace seam, read from git), with the trace off, and
with it on (a file in a temporary directory), interleaved in the same process against the same
loopback peers so that all three see the same load. Medians of repeated blocks and the ratios
to the untraced code.

    nice -n 10 .venv/bin/python bench/trace.py [--before REV] [--repeats 21] [--n 200]

Round trips: RMI ``FRC_GetStatus`` (robot.status()), Modbus function 3 of two words
(plc.read_outputs()), SCPI ``:SOUR:VOLT?`` on a pty (galvo.volts()), tracker side-car
``status`` (tracker.status()).
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.registry import open_device
from drivers.trace import WireTrace
from fakes.world import StaticWorld

#: The drivers package before the trace seam (the branch point of issue 23).
DEFAULT_BEFORE = "bbf0067"


def load_before(rev: str, into: Path) -> ModuleType:
    """The drivers package at `rev` as `drivers_before` (its own imports rewritten)."""
    pkg = into / "drivers_before"
    pkg.mkdir()
    git = ["git", "-C", str(ROOT)]
    names = subprocess.run(
        [*git, "ls-tree", "--name-only", rev, "drivers/"], check=True, capture_output=True
    ).stdout.decode()
    for name in names.split():
        text = subprocess.run(
            [*git, "show", f"{rev}:{name}"], check=True, capture_output=True
        ).stdout.decode()
        for old in ("from drivers.", "from drivers import", '"drivers.'):
            text = text.replace(old, old.replace("drivers", "drivers_before"))
        (pkg / Path(name).name).write_text(text)
    sys.path.insert(0, str(into))
    return importlib.import_module("drivers_before.registry")


def peers(stack: ExitStack) -> dict[str, tuple[str, str, Callable[[Any], Any]]]:
    """name -> (family, URL, one round trip) on loopback peers."""
    from fakes.plc import PlcServer
    from fakes.rmi_controller import RmiController
    from fakes.scpi_dac import ScpiDac
    from fakes.tracker_service import TrackerService

    world = StaticWorld()
    rmi = stack.enter_context(RmiController(world))
    plc = stack.enter_context(PlcServer())
    dac = stack.enter_context(ScpiDac())
    trk = stack.enter_context(TrackerService(world))
    return {
        "RMI FRC_GetStatus": ("robot", f"rmi://127.0.0.1:{rmi.port}", lambda d: d.status()),
        "Modbus fc3, 2 words": (
            "plc",
            f"plc+modbus://127.0.0.1:{plc.port}",
            lambda d: d._read_retrying(lambda: d._link.read(10, 2)),
        ),
        "SCPI :SOUR:VOLT?": ("galvo", f"scpi+serial://{dac.port}", lambda d: d.volts()),
        "tracker status": ("tracker", f"tracker+tcp://127.0.0.1:{trk.port}", lambda d: d.status()),
    }


def block_us(device: Any, op: Callable[[Any], Any], n: int) -> float:
    """Median round trip [us] of n calls."""
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        op(device)
        times.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=DEFAULT_BEFORE)
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--n", type=int, default=200, help="round trips per block")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, ExitStack() as stack:
        before = load_before(args.before, Path(tmp))
        trace = stack.enter_context(WireTrace(Path(tmp) / "wire.jsonl", every_device=True))
        results: dict[str, dict[str, list[float]]] = {}
        for name, (family, url, op) in peers(stack).items():
            devices = {
                "untraced": stack.enter_context(before.open_device(family, url)),
                "trace off": stack.enter_context(open_device(family, url)),
                "trace on": stack.enter_context(open_device(family, url, trace=trace)),
            }
            runs: dict[str, list[float]] = {k: [] for k in devices}
            for _ in range(args.repeats):  # interleaved: the three see the same load
                for kind, device in devices.items():
                    runs[kind].append(block_us(device, op, args.n))
            results[name] = runs
        size_kb = sum(p.stat().st_size for p in Path(tmp).glob("wire.jsonl*")) / 1024
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    print(
        f"round trip [us], median of {args.repeats} blocks of {args.n} (each block's median);"
        f" untraced = drivers at {args.before}; load average {load}"
    )
    print(
        f"{'round trip':<22}{'untraced':>10}{'trace off':>11}{'trace on':>10}"
        f"{'off/untraced':>14}{'on/untraced':>13}"
    )
    for name, runs in results.items():
        m = {k: statistics.median(v) for k, v in runs.items()}
        print(
            f"{name:<22}{m['untraced']:>10.1f}{m['trace off']:>11.1f}{m['trace on']:>10.1f}"
            f"{m['trace off'] / m['untraced']:>14.3f}{m['trace on'] / m['untraced']:>13.3f}"
        )
    print(f"trace written: {size_kb:.0f} KiB")


if __name__ == "__main__":
    main()
