"""The simulated line's devices as their own process (`rvis devices sim`) and the unchanged
service on the cell file it writes (`rvis run --cell`), two processes as at a plant (issue 40,
item 1): measurements flow; the PLC switched off through the devices' control socket puts the
service in FAULT with an alarm naming the PLC and its URL; switched on again and the fault
reset by the operator (a device lost while running waits for a reset, docs/operations.md), the
service measures again within 2 clamp windows, the same process throughout.

The devices run on the wall clock (a clamp window of 4 s every 6 s); the test waits on the
service's log lines and the devices' replies, each with a deadline."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.groups import GIGE_CAMERA
from tests.ops.conftest import ROOT, RVIS, ServiceProcess, _plant_signals, rvis, status

pytestmark = [GIGE_CAMERA, pytest.mark.slow]

PERIOD_S, WINDOW_S = 6.0, 4.0  # the clamp cycle on the devices' clock (1 sim s per real s)
CELL = f"""
[planning]
grid_step_deg = 15.0
[sweep]
n_frames = 12
[simline]
period_s = {PERIOD_S}
window_s = {WINDOW_S}
warmup_k = 0.0
"""


class DevicesProcess:
    """`rvis devices sim --json` as a child process: its first stdout line is its status once
    every device is up and the folder written; its stderr lines (what it says to a person)
    are read as they come."""

    def __init__(self, folder: Path, cell: Path) -> None:
        argv = [*RVIS, "devices", "sim", "--json", "--dir", str(folder), "--cell", str(cell)]
        self.folder = folder
        self.proc = subprocess.Popen(
            [*argv, "--seed", "3"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=ROOT,
            start_new_session=True,
            preexec_fn=_plant_signals,  # Ctrl-C reaches it as a terminal's would
            text=True,
        )
        self._lines: queue.Queue[str] = queue.Queue()
        self._said: queue.Queue[str] = queue.Queue()
        self._err: list[str] = []
        self.stderr: str | None = None
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self._err_reader = threading.Thread(target=self._read_err, daemon=True)
        self._err_reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put("")  # the end: no status comes any more

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self._err.append(line)
            self._said.put(line)
        self._said.put("")

    def ready(self, timeout_s: float = 120.0) -> dict[str, Any]:
        try:
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise AssertionError(f"devices not up in {timeout_s} s") from None
        if not line:
            self._err_reader.join(30)
            raise AssertionError(f"the devices ended ({self.proc.wait(30)}): {''.join(self._err)}")
        doc: dict[str, Any] = json.loads(line)
        return doc

    def said(self, text: str, timeout_s: float = 120.0) -> str:
        """The first stderr line from now on that holds `text`."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self._said.get(timeout=left)
            except queue.Empty:
                break
            if not line:
                break  # ended
            if text in line:
                return line
        raise AssertionError(f"no {text!r} in {timeout_s} s; it said: {''.join(self._err)}")

    def ctl(self, *words: str) -> dict[str, Any]:
        out = rvis("devices", "ctl", "--json", "--dir", str(self.folder), *words)
        reply: dict[str, Any] = json.loads(out.stdout)
        assert out.returncode == (0 if reply["ok"] else 1), out.stderr
        return reply

    def stop(self) -> tuple[int, str]:
        """Ctrl-C (idempotent): the exit status and what it wrote on stderr."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
        try:
            code = self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)  # a test failed while it was starting
            code = self.proc.wait(60)
        if self.stderr is None:
            assert self.proc.stderr is not None and self.proc.stdout is not None
            self._err_reader.join(30)
            self.stderr = "".join(self._err)
            self.proc.stderr.close()
            self._reader.join(30)
            self.proc.stdout.close()
        return code, self.stderr

    def terminate(self, timeout_s: float = 60.0) -> int:
        """SIGTERM, as a supervisor stops it; its exit status."""
        os.killpg(self.proc.pid, signal.SIGTERM)
        return self.proc.wait(timeout_s)


@pytest.fixture
def devices(tmp_path: Path) -> Iterator[DevicesProcess]:
    base = tmp_path / "base.toml"
    base.write_text(CELL, encoding="utf-8")
    proc = DevicesProcess(tmp_path / "sim", base)
    try:
        yield proc
    finally:
        proc.stop()


def _windows_opened(t0_s: float, t1_s: float) -> int:
    """How many clamp windows opened in (t0_s, t1_s] of the devices' clock."""
    opened = 0
    k = 0
    while (opens := (k + 1) * PERIOD_S - WINDOW_S) <= t1_s:
        opened += opens > t0_s
        k += 1
    return opened


def test_the_service_on_the_devices_process_faults_on_the_plc_and_measures_again(
    devices: DevicesProcess,
) -> None:
    up = devices.ready()
    plc_url = up["devices"]["plc"]["url"]
    assert {d["state"] for d in up["devices"].values()} == {"up"}
    assert set(up["devices"]) == {"robot", "camera", "galvo", "tracker", "plc"}
    cell = Path(up["cell"])
    service = ServiceProcess(devices.folder, cell, argv=[*RVIS, "run", "--cell", str(cell)])
    try:
        service.wait_log(lambda r: r.get("event") == "measurement", 60.0)
        service.wait_log(lambda r: r.get("event") == "measurement", 3 * PERIOD_S)
        pid = service.proc.pid

        reply = devices.ctl("stop", "plc")
        assert reply["devices"]["plc"]["state"] == "stopped"
        service.wait_log(
            lambda r: r.get("event") == "alarm" and r["data"]["code"] == "device_fault", 30.0
        )
        doc = status(devices.folder)
        assert doc["state"] == "fault"
        [alarm] = [a for a in doc["alarms"] if a["code"] == "device_fault"]
        assert alarm["text"].startswith(f"plc ({plc_url}): DeviceConnectionError")
        assert doc["devices"]["plc"]["state"] == "fault"

        reply = devices.ctl("start", "plc")
        assert reply["devices"]["plc"]["state"] == "up"
        out = rvis("ctl", "--state-dir", str(devices.folder), "reset")
        assert out.returncode == 0, out.stderr
        reset = service.wait_log(
            lambda r: r.get("event") == "operator" and r["data"]["cmd"] == "reset", 10.0
        )
        measured = service.wait_log(lambda r: r.get("event") == "measurement", 4 * PERIOD_S)
        # the PLC's windows (the devices' clock) opened between the two (the service's clock)
        epoch = up["started_unix_s"]
        assert _windows_opened(reset["t"] - epoch, measured["t"] - epoch) <= 2
        doc = status(devices.folder)
        assert doc["state"] in ("idle", "measuring")
        assert not [a for a in doc["alarms"] if a["code"] == "device_fault"]
        assert doc["devices"]["plc"]["state"] == "ok"
        assert service.alive and service.proc.pid == pid  # no restart
        code = service.stop()
    finally:
        if service.alive:
            service.stop()
    assert code == 0, service.stderr
    assert "Traceback" not in service.stderr
    code, err = devices.stop()
    assert code == 0 and "Traceback" not in err
    assert not (devices.folder / "devices.sock").exists()


def test_the_control_socket_names_what_it_cannot_do(devices: DevicesProcess) -> None:
    devices.ready()
    assert devices.ctl("break", "tracker") == {
        "ok": False,
        "error": "tracker has no break (stop it instead)",
    }
    assert not devices.ctl("stop", "gripper")["ok"]
    assert not devices.ctl("reboot")["ok"]
    reply = devices.ctl("break", "camera")
    assert reply["ok"] and reply["devices"]["camera"]["state"] == "broken"
    assert devices.ctl("fix", "camera")["devices"]["camera"]["state"] == "up"
    assert devices.ctl("quit")["ok"]
    assert devices.proc.wait(60) == 0
    out = rvis("devices", "ctl", "--dir", str(devices.folder), "status")
    assert out.returncode == 2 and "rvis devices sim --dir" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
