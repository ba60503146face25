"""`rvis run --sim` writes JSON lines only on stdout, for jq and log shippers (issue 30: 14 of
919 lines were text such as `window 10 ... true RMSE ...`); the words for a person (the start
line, a batch run's summary) go to stderr (docs/operations.md, "What the service prints")."""

from __future__ import annotations

import json
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from app.line.events import JsonLineFormatter

ROOT = Path(__file__).resolve().parents[2]
RVIS = [sys.executable, "-m", "app", "run", "--sim", "--geometric"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def strict(line: str) -> dict[str, Any]:
    """One stdout line as a JSON object; NaN or Infinity are not JSON (jq refuses them)."""

    def refuse(constant: str) -> None:
        raise ValueError(f"{constant} in {line!r}")

    obj = json.loads(line, parse_constant=refuse)
    assert isinstance(obj, dict), line
    return obj


def test_a_batch_run_prints_json_lines_only(tmp_path: Path) -> None:
    argv = [*RVIS, "--windows", "2", "--state-dir", str(tmp_path / "state")]
    done = subprocess.run(argv, cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = [strict(line) for line in done.stdout.splitlines()]
    windows = [r["data"] for r in lines if r.get("event") == "sim_window"]
    assert [w["window"] for w in windows] == [1, 2]
    assert all(w["rmse_mm"] > 0 and w["version"] >= 1 for w in windows)
    assert all("u95_mm" in w and "suspect" not in w for w in windows)  # (known at the end only)
    (summary,) = [r["data"] for r in lines if r.get("event") == "sim_summary"]
    assert summary["windows"] == 2 and lines[-1]["event"] == "sim_summary"
    started, said = done.stderr.splitlines()  # for a person: the start and the summary
    assert started.startswith("rvis run --sim: seed 0") and said.startswith("2 windows, ")


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_the_service_prints_json_lines_only(tmp_path: Path) -> None:
    """The service (no --windows) until it is stopped: its log and the simulation's lines."""
    argv = [*RVIS, "--state-dir", str(tmp_path / "state")]
    lines: queue.Queue[str] = queue.Queue()
    seen: list[str] = []
    with subprocess.Popen(
        argv, cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    ) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        out = proc.stdout

        def pump() -> None:
            for line in out:
                lines.put(line)

        reader = threading.Thread(target=pump)
        reader.start()
        try:
            deadline = time.monotonic() + 120
            while not any('"sim_window"' in line and '"window": 3,' in line for line in seen):
                seen.append(lines.get(timeout=max(0.0, deadline - time.monotonic())))
        finally:
            proc.send_signal(signal.SIGTERM)
            err = proc.stderr.read()
            proc.wait(timeout=120)
            reader.join(timeout=120)
    seen += list(lines.queue)
    assert proc.returncode == 0, err
    records = [strict(line) for line in seen]
    events = {r.get("event") for r in records}
    assert {"started", "window", "sim_window", "stopped"} <= events
    assert [line for line in err.splitlines() if not line.startswith("rvis run --sim:")] == []


def test_a_log_line_with_nan_is_still_json() -> None:
    """A NaN in an event's data (a rejected measurement's residual) is null on the line."""
    record = logging.LogRecord("rvis.line", logging.INFO, __file__, 1, "measurement", None, None)
    record.event = "measurement"
    record.data = {"residual_mm": float("nan"), "span": [float("inf"), 1.0]}
    line = strict(JsonLineFormatter().format(record))
    assert line["data"] == {"residual_mm": None, "span": [None, 1.0]}
