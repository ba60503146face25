"""The operator's terminal under load (not run by the tests), headless (Textual's Pilot):

- latency: from an alarm raised by the simulated service (its own `_alarm`: database row and
  event) to the alarm's text in the TUI's banner, same process, geometric line at time x60;
- CPU of the attached TUI: a simulated service runs in a child process (`rvis run --sim
  --geometric`); this process holds only the TUI; CPU seconds per wall second over 3 s spans,
  with the service paused (idle screen) and running (events every few ms of real time).

Prints medians of repeated runs (target: latency <= 250 ms).

    nice -n 5 .venv/bin/python bench/tui.py [--repeats 15]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import subprocess
import sys
import tempfile
import time
from multiprocessing import resource_tracker
from pathlib import Path

from app.config import load_cell
from app.sim.line_run import SimulatedLineRun
from app.sim.tui_line import TuiSimSettings, simulated_service
from app.tui.app import RvisTui


def banner(app: RvisTui) -> str:
    return str(app.query_one("#banner").render())


async def latency_ms(run: SimulatedLineRun, repeats: int) -> list[float]:
    svc, out = run.service, []
    app = RvisTui(run.state_dir)
    async with app.run_test(size=(120, 40)) as pilot:
        while app.status is None:
            await pilot.pause(0.05)
        for k in range(repeats):
            message = f"bench alarm {k}"
            t0 = time.perf_counter()
            svc.alarm(f"bench{k}", message, "high")
            while message not in banner(app):
                await pilot.pause(0.002)
            out.append(1e3 * (time.perf_counter() - t0))
            svc.store.clear_alarms(svc.clock.time(), f"bench{k}")
            svc.bus.emit("alarm_cleared", {"code": f"bench{k}"})
            while "bench" in banner(app):
                await pilot.pause(0.01)
    return out


async def cpu_fraction(state_dir: Path, spans: int, span_s: float) -> dict[str, list[float]]:
    """CPU fraction of this process (the TUI only) with the service running, then paused."""
    app = RvisTui(state_dir)
    out: dict[str, list[float]] = {"running": [], "paused": []}
    async with app.run_test(size=(120, 40)) as pilot:
        while app.status is None:
            await pilot.pause(0.05)
        for phase in ("running", "paused"):
            if phase == "paused":
                reply = await app.client.request("pause")
                assert reply["ok"], reply
            await pilot.pause(1.0)
            for _ in range(spans):
                c0, t0 = time.process_time(), time.perf_counter()
                await pilot.pause(span_s)
                out[phase].append((time.process_time() - c0) / (time.perf_counter() - t0))
    return out


def cpu_runs(spans: int) -> dict[str, list[float]]:
    with tempfile.TemporaryDirectory() as d:
        state = Path(d)
        argv = [
            sys.executable,
            "-m",
            "app",
            "run",
            "--sim",
            "--geometric",
            "--state-dir",
            d,
        ]
        child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            while not (state / "rvis.sock").exists():
                time.sleep(0.1)  # a bench, not a test: waiting for the child's socket
            return asyncio.run(cpu_fraction(state, spans, 3.0))
        finally:
            child.terminate()
            child.wait(30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    resource_tracker.ensure_running()
    with (
        tempfile.TemporaryDirectory() as d,
        simulated_service(load_cell(None), d, TuiSimSettings(scale=60.0)) as run,
    ):
        lat = asyncio.run(latency_ms(run, args.repeats))
    cpu = cpu_runs(max(3, args.repeats // 3))
    idle, running = cpu["paused"], cpu["running"]
    print(f"{'measure':44s} {'median':>10s} {'min':>10s} {'max':>10s}  n")
    for name, values, unit in (
        ("alarm raised -> banner shows it", lat, "ms"),
        ("TUI CPU, service paused (idle screen)", [100 * v for v in idle], "%"),
        ("TUI CPU, service running (time x60)", [100 * v for v in running], "%"),
    ):
        med, lo, hi = statistics.median(values), min(values), max(values)
        cells = " ".join(f"{v:8.1f}{unit:>2s}" for v in (med, lo, hi))
        print(f"{name:44s} {cells}  {len(values)}")


if __name__ == "__main__":
    main()
