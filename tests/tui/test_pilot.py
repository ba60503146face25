"""The operator's terminal driven by Textual's Pilot against a REAL running service: the
simulated line (geometric) and its service in a temp state directory, reached over the control
socket. Assertions are on the screen and on the service's own state (its database, read through
a separate read-only connection, and its parameters version).

The line of these tests leaves the service a wide margin whatever the machine's load: a clamp
window of 24 s in a 30 s cycle at time x40 (0.6 s of real time to start a motion, where the
service needs a few ms), up to 4 slots per window (a recalibration's 28 measurements in a few
windows), and the service starts 40 sim minutes into the cell's warm-up (the commissioning
parameters are visibly off, so an in-line calibration passes its gates). The time in which
the service only waits for the next window is skipped (IdleSkipper advances the line's clock),
and keys are pressed without Pilot's wait for an idle process, which never comes with a
service running in this process. Each wait is on a condition of the screen or the database
with a generous timeout; none depends on drift alarms being absent.
"""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import replace
from datetime import UTC, datetime
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Any

import pytest
from textual.pilot import Pilot
from textual.widgets import DataTable

from app.config import CellConfig, load_cell
from app.sim.line_run import SimulatedLineRun
from app.sim.tui_line import TuiSimSettings, simulated_service
from app.tui.app import RvisTui
from app.tui.history import HistoryReader
from tests.tui.helpers import IdleSkipper, confirm, press, text_of, until

SIM = TuiSimSettings(geometric=True, seed=3, scale=40.0, mode="approve", start_at_s=2400.0)
#: generous: each wait normally ends in well under a second
WAIT_S = 60.0


def pilot_cell() -> CellConfig:
    cfg = load_cell(None)
    return replace(
        cfg,
        simline=replace(cfg.simline, period_s=30.0, window_s=24.0),
        line=replace(cfg.line, slots_per_window=4),
    )


@pytest.fixture
def service(tmp_path: Path) -> Iterator[SimulatedLineRun]:
    with simulated_service(pilot_cell(), tmp_path, SIM) as run:
        yield run


@pytest.fixture
def skipper(service: SimulatedLineRun) -> Iterator[IdleSkipper]:
    with IdleSkipper(service) as skipper:
        yield skipper


def _alarms(run: SimulatedLineRun, code: str) -> list[dict[str, Any]]:
    """The service's alarms with this code, from its database (read-only)."""
    return [a for a in HistoryReader(run.state_dir / "rvis.db").alarms() if a["code"] == code]


def test_fault_raises_an_alarm_the_operator_acknowledges_and_resets(
    service: SimulatedLineRun, skipper: IdleSkipper
) -> None:
    async def scenario() -> None:
        app = RvisTui(service.state_dir)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: _attached(app), WAIT_S)
            assert _alarms(service, "device_fault") == []
            # the next motion stops half-way on a controller alarm; played between two
            # windows, it meets the first motion of the next one (which has the whole window)
            injected = skipper.between_windows(lambda: service.line.inject("controller_alarm"))
            await until(pilot, injected.is_set, WAIT_S)
            await until(pilot, lambda: bool(_alarms(service, "device_fault")), WAIT_S)
            (alarm,) = _alarms(service, "device_fault")
            assert alarm["state"] == "raised" and alarm["priority"] == "urgent"
            await until(pilot, lambda: "ALARM URGENT" in text_of(app, "#banner"), WAIT_S)
            assert str(alarm["message"]) in text_of(app, "#banner")  # the most urgent one
            await until(pilot, lambda: text_of(app, "#status").startswith("fault"), WAIT_S)
            assert service.service.state.value == "fault"
            await press(pilot, "4")  # the Alarms pane: select the fault's row, acknowledge it
            table: DataTable[Any] = app.query_one("#alarms-table", DataTable)
            await until(pilot, lambda: _row_of(table, alarm["id"]) is not None, WAIT_S)
            table.move_cursor(row=_row_of(table, alarm["id"]))
            await press(pilot, "k")
            await until(pilot, lambda: _alarms(service, "device_fault")[0]["state"] == "acked")
            assert _alarms(service, "device_fault")[0]["acked_uid"] is not None
            await until(pilot, lambda: "[acknowledged]" in text_of(app, "#banner"), WAIT_S)
            await _devices_show_the_fault_then_reset(pilot, app, service, alarm)

    asyncio.run(scenario())


async def _devices_show_the_fault_then_reset(
    pilot: Pilot[None], app: RvisTui, service: SimulatedLineRun, alarm: dict[str, Any]
) -> None:
    """The Devices pane: the robot in FAULT with the error (whole, under the table) and its
    time, the others OK; after a reset the robot is OK again and its last error still shown."""
    await press(pilot, "5")
    table: DataTable[Any] = app.query_one("#devices-table", DataTable)
    rows = lambda: {str(r[0]): r for r in map(table.get_row_at, range(table.row_count))}  # noqa: E731
    await until(pilot, lambda: rows().get("robot", ("",) * 3)[1] == "FAULT", WAIT_S)
    errors = {line.split("  ")[0].strip(): line for line in _error_lines(app)}
    assert set(errors) == {"robot"}  # the only device that failed
    when, message = errors["robot"].split("  ", 1)[1].split("  ", 1)
    assert alarm["message"] == f"robot ({service.line.urls['robot']}): {message}"  # named
    at = datetime.fromisoformat(when).replace(tzinfo=UTC).timestamp()
    assert abs(at - alarm["t_raised"]) < 5.0  # sim seconds: the same moment
    others = [r for family, r in rows().items() if family != "robot"]
    assert others and all(r[1] == "OK" for r in others)
    await confirm(pilot, "r")
    await until(pilot, lambda: rows()["robot"][1] == "OK", WAIT_S)
    assert _error_lines(app) == list(errors.values())  # kept after the reset
    assert _alarms(service, "device_fault")[0]["state"] == "cleared"


def _error_lines(app: RvisTui) -> list[str]:
    """The lines of the devices' last errors under their table (app.tui.view.device_errors)."""
    return text_of(app, "#device-errors").splitlines()[1:]


def _row_of(table: DataTable[Any], alarm_id: int) -> int | None:
    ids = [str(table.get_row_at(k)[0]) for k in range(table.row_count)]
    return ids.index(str(alarm_id)) if str(alarm_id) in ids else None


def test_approve_then_roll_back(service: SimulatedLineRun, skipper: IdleSkipper) -> None:
    svc = service.service
    history = HistoryReader(service.state_dir / "rvis.db")

    async def scenario() -> None:
        app = RvisTui(service.state_dir)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.client.connected and app.status is not None, WAIT_S)
            v0 = svc.version
            await confirm(pilot, "c")
            await until(pilot, lambda: (app.status or {}).get("pending") is not None, WAIT_S)
            pending = (app.status or {})["pending"]
            assert pending["id"] == svc.decision.pending_calibration and pending["parameters"]
            await confirm(pilot, "a")
            # the service's answer: the calibration applied, a new version in force (database)
            await until(pilot, lambda: _latest_applied(history)["source"] == "approved", WAIT_S)
            (cal,) = [c for c in history.calibrations() if c["id"] == pending["id"]]
            v1 = _latest_applied(history)["version"]
            assert cal["status"] == "applied" and cal["version"] == v1 != v0
            assert svc.version == v1
            await press(pilot, "3")
            table: DataTable[Any] = app.query_one("#versions-table", DataTable)
            await until(pilot, lambda: table.row_count >= 2, WAIT_S)
            table.move_cursor(row=table.row_count - 1)  # the oldest: the commissioning version
            assert str(table.get_row_at(table.cursor_row)[0]) == str(v0)
            await confirm(pilot, "b")
            await until(pilot, lambda: _latest_applied(history)["source"] == "rollback", WAIT_S)
            assert _latest_applied(history)["version"] == v0 and svc.version == v0

    asyncio.run(scenario())


def _latest_applied(history: HistoryReader) -> dict[str, Any]:
    """The parameters version put in force last, from the service's database."""
    return history.applied(limit=1)[0]


@pytest.mark.slow  # a service in a child process: its start takes a few seconds
def test_killed_service_shows_disconnected_and_the_terminal_reconnects(tmp_path: Path) -> None:
    """A service in its own process (`rvis run --sim`) killed with SIGKILL (its socket file
    stays behind), then a service back on the same state directory, stopped cleanly."""
    resource_tracker.ensure_running()  # before Textual replaces sys.stderr (app/sim/tui_line.py)
    run_sim = [sys.executable, "-m", "app", "run", "--sim", "--geometric"]

    async def scenario() -> None:
        app = RvisTui(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: _disconnected(app))
            child = subprocess.Popen(
                [*run_sim, "--state-dir", str(tmp_path)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            try:
                await until(pilot, lambda: _attached(app), WAIT_S)
                assert not app.query_one("#status").has_class("disconnected")
            finally:
                child.kill()
                await asyncio.to_thread(child.wait, WAIT_S)
            await until(pilot, lambda: _disconnected(app), WAIT_S)
            assert (tmp_path / "rvis.sock").exists()  # nobody listens on it any more
            # started and stopped in a thread: the simulated line runs its own event loops
            stack = contextlib.ExitStack()
            await asyncio.to_thread(
                stack.enter_context, simulated_service(pilot_cell(), tmp_path, SIM)
            )
            try:
                await until(pilot, lambda: _attached(app), WAIT_S)
            finally:
                await asyncio.to_thread(stack.close)
            await until(pilot, lambda: _disconnected(app), WAIT_S)

    asyncio.run(scenario())


def _disconnected(app: RvisTui) -> bool:
    status = app.query_one("#status")
    return text_of(app, "#status").startswith("DISCONNECTED") and status.has_class("disconnected")


def _attached(app: RvisTui) -> bool:
    """The status line shows the service's state (one of its states, lower case)."""
    state = text_of(app, "#status").split(" ", 1)[0]
    return state in ("idle", "measuring", "paused", "fault", "starting")
