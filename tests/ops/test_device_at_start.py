"""`rvis run` (the real command, its own process) on the simulated line's device peers, with the
PLC's port closed at start (issue 30, item 4): the service does not exit; it answers `rvis
status` in FAULT with a `device_unreachable` alarm naming the PLC, retries with back-off, and
once the PLC's port opens leaves FAULT by itself and measures within 2 windows. SIGTERM during
the retries is a clean stop. No raw pymodbus line reaches the terminal.

The peers run in this process (fakes.line.SimLine on a scaled wall clock, rendered: camera and
galvo), the PLC apart on a port chosen here and opened when the test says; the service runs on
the wall clock, its [line] window the peers' window in wall seconds."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.config import load_cell
from app.sim.cell import make_cell
from app.sim.line_setup import simline_settings
from fakes.line import SimLine
from fakes.line_faults import LinePlc
from tests.ops.conftest import RVIS, ServiceProcess, rvis
from tests.ports import free_port

SCALE = 2.0  # sim seconds per wall second of the peers
PERIOD_S, WINDOW_S = 12.0, 8.0  # the clamp cycle, sim seconds: a window of 4 s every 6 s
WALL_PERIOD_S = PERIOD_S / SCALE
CELL = f"""
[planning]
grid_step_deg = 15.0
[sweep]
n_frames = 12
[line]
window_s = {WINDOW_S / SCALE}
margin_s = 0.2
"""


@contextlib.contextmanager
def _peers(tmp_path: Path, *, camera: bool) -> Iterator[tuple[SimLine, Path, int]]:
    """The simulated line's peers (the PLC left out: port `plc_port`, closed; without `camera`
    no GigE fake either, the camera's URL an address where none answers) and a cell file
    naming them, with a plan."""
    base = tmp_path / "base.toml"
    base.write_text(CELL, encoding="utf-8")
    cfg = load_cell(base)
    setup = replace(
        simline_settings(cfg, geometric=not camera),
        warmup=None,
        clock="scaled",
        scale=SCALE,
        period_s=PERIOD_S,
        window_s=WINDOW_S,
    )
    plc_port = free_port()
    with SimLine(make_cell(cfg, seed=cfg.simulation.seed), setup) as sim:
        urls = {"camera": "aravis://127.0.0.3", **sim.urls}
        urls["plc"] = f"plc+modbus://127.0.0.1:{plc_port}"
        devices = "\n".join(f'{k} = "{v}"' for k, v in urls.items())
        cell = tmp_path / "cell.toml"
        cell.write_text(f"{CELL}\n[devices]\n{devices}\n", encoding="utf-8")
        plan = ["plan", "--cell", str(cell), "--placement", "fixed", "--out"]
        assert main([*plan, str(tmp_path / "plan.json")]) == 0
        yield sim, cell, plc_port


@pytest.fixture
def line(tmp_path: Path) -> Iterator[tuple[SimLine, Path, int]]:
    with _peers(tmp_path, camera=True) as peers:
        yield peers


def _start(tmp_path: Path, cell: Path) -> ServiceProcess:
    argv = [*RVIS, "run", "--cell", str(cell), "--plan", str(tmp_path / "plan.json")]
    return ServiceProcess(tmp_path / "state", cell, argv=argv)


def _status(state: Path) -> dict[str, Any]:
    out = rvis("status", "--state-dir", str(state), "--json")
    assert out.returncode == 0, out.stderr
    doc: dict[str, Any] = json.loads(out.stdout)
    return doc


def _wait_fault(service: ServiceProcess) -> dict[str, Any]:
    """The status reply once the service is up in FAULT (the socket answers after it logged
    its alarm; no sleep: the log line is the signal)."""
    service.wait_log(
        lambda r: r.get("event") == "alarm" and r["data"]["code"] == "device_unreachable", 60.0
    )
    return _status(service.state_dir)


def test_a_plc_unreachable_at_start_is_a_fault_on_the_socket_until_its_port_opens(
    tmp_path: Path, line: tuple[SimLine, Path, int]
) -> None:
    sim, cell, plc_port = line
    t0 = time.monotonic()
    service = _start(tmp_path, cell)
    try:
        status = _wait_fault(service)
        fault_s = time.monotonic() - t0
        assert status["state"] == "fault"
        [alarm] = [a for a in status["alarms"] if a["code"] == "device_unreachable"]
        assert alarm["text"].startswith(f"plc (plc+modbus://127.0.0.1:{plc_port}) unreachable")
        assert status["devices"]["plc"]["state"] == "unreachable"
        assert status["devices"]["robot"]["state"] == "ok"
        assert "waiting for plc" in status["step"]
        # an operator's reset cannot help: said so
        out = rvis("ctl", "--state-dir", str(service.state_dir), "reset")
        assert out.returncode == 1 and "no reset needed" in out.stderr
        assert service.alive

        with LinePlc(setup_cycle(sim), sim.clock, port=plc_port):
            opened = time.monotonic()
            service.wait_log(lambda r: r.get("event") == "devices_opened", 40.0)
            service.wait_log(
                lambda r: r.get("event") == "state" and r["data"]["to"] == "idle", 10.0
            )
            service.wait_log(lambda r: r.get("event") == "measurement", 3 * WALL_PERIOD_S)
            measured = time.monotonic() - opened
            status = _status(service.state_dir)
            assert status["state"] in ("idle", "measuring")
            assert not [a for a in status["alarms"] if a["code"] == "device_unreachable"]
            assert status["devices"]["plc"]["state"] == "ok"
            assert status["measurements"]["ok"] + status["measurements"]["rejected"] >= 1
            code = service.stop()
    finally:
        if service.alive:
            service.stop()
    assert code == 0, service.stderr
    windows = measured / WALL_PERIOD_S
    print(f"FAULT on the socket {fault_s:.1f} s after the start; first measurement")
    print(f"{measured:.1f} s = {windows:.2f} windows after the port opened")
    assert measured <= 2 * WALL_PERIOD_S
    assert "Connection to" not in service.stderr  # pymodbus's own line
    assert "plc unreachable" in service.stderr and "Traceback" not in service.stderr


def setup_cycle(sim: SimLine) -> Any:
    return sim.settings.cycle


def test_sigterm_during_the_retries_is_a_clean_stop(tmp_path: Path) -> None:
    """Two devices unreachable (the PLC, and the camera: no GigE fake, each try 2-3 s)."""
    with _peers(tmp_path, camera=False) as (_, cell, plc_port):
        service = _start(tmp_path, cell)
        try:
            status = _wait_fault(service)
            [alarm] = [a for a in status["alarms"] if a["code"] == "device_unreachable"]
            assert alarm["text"].startswith(f"plc (plc+modbus://127.0.0.1:{plc_port})")
            assert "; camera (aravis://127.0.0.3) unreachable" in alarm["text"]
            assert status["devices"]["camera"]["state"] == "unreachable"
            service.wait_log(lambda r: r.get("event") == "device_retry", 20.0)  # retrying
        finally:
            t0 = time.monotonic()
            code = service.stop()
            stop_s = time.monotonic() - t0
    assert code == 0, service.stderr
    assert stop_s < 10.0  # at most a try in progress (the camera's: 2-3 s), then out
    assert "Traceback" not in service.stderr and "Connection to" not in service.stderr
    assert not (service.state_dir / "rvis.sock").exists()
    assert _status(service.state_dir)["state"] == "not running"
