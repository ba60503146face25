"""The operator's terminal driven by Textual's Pilot against a REAL running service: the
simulated line (geometric, time x200) and its service in a temp state directory, reached over
the control socket. Assertions are on the screen and on the service's own state (its database,
its parameters version)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from multiprocessing import resource_tracker
from pathlib import Path

import pytest
from textual.widgets import DataTable

from app.config import load_cell
from app.sim.line_run import SimulatedLineRun
from app.tui.app import RvisTui
from app.tui.sim import TuiSimSettings, simulated_service
from tests.tui.helpers import text_of, until

SIM = TuiSimSettings(geometric=True, seed=3, scale=200.0, mode="approve")


@pytest.fixture
def service(tmp_path: Path) -> Iterator[SimulatedLineRun]:
    with simulated_service(load_cell(None), tmp_path, SIM) as run:
        yield run


@pytest.mark.skip(
    reason="flaky under load: a drift alarm can come first and the injected controller alarm "
    "then never becomes a fault within the wait (open in issue 12); passes alone"
)
def test_fault_raises_an_alarm_the_operator_acknowledges(service: SimulatedLineRun) -> None:
    async def scenario() -> None:
        app = RvisTui(service.state_dir)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: _attached(app))
            service.line.inject("controller_alarm")
            await until(pilot, lambda: "ALARM URGENT" in text_of(app, "#banner"), 40.0)
            assert "fault" in text_of(app, "#status")
            alarm = service.service.store.active_alarms()[0]
            assert alarm["state"] == "raised" and alarm["code"] == "device_fault"
            await pilot.press("k")
            await until(pilot, lambda: _alarm_state(service, alarm["id"]) == "acked")
            await until(pilot, lambda: "[acknowledged]" in text_of(app, "#banner"))

    asyncio.run(scenario())


def _alarm_state(run: SimulatedLineRun, alarm_id: int) -> str:
    return next(str(a["state"]) for a in run.service.store.alarms() if a["id"] == alarm_id)


@pytest.mark.skip(
    reason="flaky under load: the simulated service can sit 'waiting for a window' with a drift "
    "alarm for longer than the wait (open in issue 12); passes alone on a quiet machine"
)
def test_approve_then_roll_back(service: SimulatedLineRun) -> None:
    svc = service.service

    async def scenario() -> None:
        app = RvisTui(service.state_dir)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(pilot, lambda: app.client.connected and app.status is not None)
            v0 = svc.version
            await pilot.press("c", "y")
            await until(pilot, lambda: (app.status or {}).get("pending") is not None, 30.0)
            pending = (app.status or {})["pending"]
            assert pending["id"] == svc.pending_calibration and pending["parameters"]
            await pilot.press("a", "y")
            await until(pilot, lambda: svc.version != v0)
            applied = [c for c in svc.store.calibrations() if c["id"] == pending["id"]]
            assert applied[0]["status"] == "applied" and applied[0]["version"] == svc.version
            await pilot.press("3")
            await until(pilot, lambda: app.query_one("#versions-table", DataTable).row_count >= 2)
            table: DataTable[str] = app.query_one("#versions-table", DataTable)
            table.move_cursor(row=table.row_count - 1)  # the oldest: the commissioning version
            assert str(table.get_row_at(table.cursor_row)[0]) == str(v0)
            await pilot.press("b", "y")
            await until(pilot, lambda: svc.version == v0)
            assert svc.store.applied()[-1]["source"] == "rollback"

    asyncio.run(scenario())


def test_disconnected_then_reconnects_by_itself(tmp_path: Path) -> None:
    cfg = load_cell(None)
    resource_tracker.ensure_running()  # before Textual replaces sys.stderr (see app/tui/sim.py)

    async def scenario() -> None:
        app = RvisTui(tmp_path)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: text_of(app, "#status").startswith("DISCONNECTED"))
            for _ in range(2):  # a service comes, goes, and comes back on the same state dir
                # started and stopped in a thread: the simulated line runs its own event loops
                stack = contextlib.ExitStack()
                await asyncio.to_thread(stack.enter_context, simulated_service(cfg, tmp_path, SIM))
                try:
                    await until(pilot, lambda: _attached(app))
                    assert app.query_one("#status").has_class("disconnected") is False
                finally:
                    await asyncio.to_thread(stack.close)
                await until(pilot, lambda: text_of(app, "#status").startswith("DISCONNECTED"))
                assert app.query_one("#status").has_class("disconnected")

    asyncio.run(scenario())


def _attached(app: RvisTui) -> bool:
    """The status line shows the service's state (one of its states, lower case)."""
    state = text_of(app, "#status").split(" ", 1)[0]
    return state in ("idle", "measuring", "paused", "fault", "starting")
