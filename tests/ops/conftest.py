"""The operations suite: the service as the plant runs it, in its own process (`rvis run --sim
--geometric` on a fast simulated clock), with clients that are processes too. The service's
JSON log lines (stdout) are read by a thread; tests wait on them with a timeout, never sleep."""

from __future__ import annotations

import json
import os
import queue
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

# 60 s clamp cycles at x300: a window every 0.2 s; a recalibration every 8 measurements, by the
# batch estimator (said here, not left to the default): its identification runs in a worker
# process, which these tests kill and signal (the sequential one runs in the service's loop);
# on a rolling set of 24 (the paper's) and not the compliant model's 72: the first one starts
# after 28 windows (about 6 s) and not 76 (15 s). What these tests follow is how the service
# runs, stops and recovers, not how well a calibration fits
CELL = """
[simline]
scale = 300.0
[service]
every_n = 8
rolling_size = 24
estimator = "batch"
"""
RVIS = [sys.executable, "-m", "app"]
ROOT = Path(__file__).resolve().parents[2]


def _plant_signals() -> None:
    """In the service's process before it starts: the stop signals at their defaults and not
    blocked, as systemd or a terminal starts it. An ignored signal is inherited through exec:
    a suite started in the background by a non-interactive shell (`scripts/test &`) runs with
    SIGINT ignored, Python then installs no handler of its own, and the service ignored the
    Ctrl-C under test (`nohup scripts/test &`: SIGHUP, SIGINT and SIGQUIT ignored)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


class ServiceProcess:
    """`rvis run --sim --geometric --no-bodies` (or `argv`, without --state-dir) as a child
    process (its own process group). Spheres only: these tests follow the sphere cycle (its
    windows, a recalibration within a wait of wall time), which a body each window delays."""

    def __init__(self, state_dir: Path, cell: Path, argv: list[str] | None = None) -> None:
        self.state_dir, self.cell = state_dir, cell
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self.logged_ids: list[int] = []  # measurements the service announced (committed first)
        self.stderr = ""
        argv = argv or [*RVIS, "run", "--sim", "--geometric", "--no-bodies", "--cell", str(cell)]
        self.proc = subprocess.Popen(
            [*argv, "--state-dir", str(state_dir)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=ROOT,
            start_new_session=True,
            preexec_fn=_plant_signals,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            try:
                line = json.loads(raw)
                if line.get("event") == "measurement":
                    self.logged_ids.append(int(line["data"]["id"]))
                self.lines.put(line)
            except ValueError:
                self.lines.put({"raw": raw.decode(errors="replace")})

    def wait_log(self, pred: Callable[[dict[str, Any]], bool], timeout_s: float = 30.0) -> dict:
        """The first log line from now on that satisfies pred."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                break
            if pred(line):
                return line
        raise AssertionError(f"no such log line in {timeout_s} s ({self._fate()})")

    def _fate(self) -> str:
        """Alive, or how the service ended: its exit code and the end of its stderr (what a
        failed wait needs to be diagnosed)."""
        code = self.proc.poll()
        if code is None:
            return "alive: True"
        if self.proc.stderr is not None and not self.proc.stderr.closed:
            self.stderr += self.proc.stderr.read().decode(errors="replace")
        return f"alive: False, exit {code}, stderr: {self.stderr[-2000:]!r}"

    def wait_windows(self, n: int, timeout_s: float = 30.0) -> None:
        for _ in range(n):
            self.wait_log(lambda r: r.get("event") == "window", timeout_s)

    def wait_ready(self) -> None:
        self.wait_log(lambda r: r.get("event") == "state" and r["data"]["to"] == "idle", 60.0)
        self.wait_windows(1)

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill9(self) -> None:
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)
        self._close()

    def wait_exit(self, timeout_s: float = 60.0) -> int:
        """The exit code once the service ends by itself (no signal from here)."""
        code = self.proc.wait(timeout_s)
        self._close()
        return code

    def stop(self) -> int:
        if self.alive:
            os.killpg(self.proc.pid, signal.SIGTERM)
        code = self.proc.wait(60)
        self._close()
        return code

    def errors(self) -> list[str]:
        """The internal errors the service logged (after it ended), with their tracebacks."""
        out: list[str] = []
        while True:
            try:
                line = self.lines.get_nowait()
            except queue.Empty:
                return out + ([self.stderr] if self.stderr.strip() else [])
            if line.get("level") == "error":
                out.append(f"{line.get('msg')}\n{line.get('exc', '')}")

    def _close(self) -> None:
        assert self.proc.stdout is not None and self.proc.stderr is not None
        self._reader.join(30)
        self.stderr += self.proc.stderr.read().decode(errors="replace")
        self.proc.stdout.close()
        self.proc.stderr.close()


def rvis(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*RVIS, *args], capture_output=True, text=True, cwd=ROOT, timeout=timeout_s
    )


def count(db: Path, sql: str) -> int:
    """One number from the state database, read-only (`SELECT COUNT(*) ...`)."""
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return int(con.execute(sql).fetchone()[0])
    finally:
        con.close()


def status(state_dir: Path) -> dict[str, Any]:
    out = rvis("status", "--state-dir", str(state_dir), "--json")
    assert out.returncode == 0, out.stderr
    result: dict[str, Any] = json.loads(out.stdout)
    return result


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(CELL, encoding="utf-8")
    return path


@pytest.fixture
def service(tmp_path: Path, cell: Path) -> Iterator[ServiceProcess]:
    svc = ServiceProcess(tmp_path / "state", cell)
    try:
        svc.wait_ready()
        yield svc
    finally:
        if svc.alive:
            svc.stop()
