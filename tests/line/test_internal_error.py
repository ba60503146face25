"""An unexpected error anywhere in the service (issue 19): in its loop or a connection thread of
the control socket it is logged with its traceback, raised as an urgent `internal_error` alarm,
puts the cell in FAULT (robot stopped, PLC fault bit) and ends `run()` with exit code 1 so that
the supervisor restarts the process; the restarted service stays in FAULT until a reset.
(A worker process killed by the system: tests/ops.)"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import pytest

from app.line.launch import serving
from app.line.states import State
from app.line.store import Store
from tests.line.helpers import Line, make_line


class Aborts:
    """Counts the robot's aborts (the cell stopped) without changing what they do."""

    def __init__(self, ln: Line) -> None:
        self.n = 0
        original = ln.robot.abort

        def counted() -> None:
            self.n += 1
            original()

        ln.robot.abort = counted  # type: ignore[method-assign]


def _run_to_exit(ln: Line, timeout_s: float = 20.0) -> None:
    assert ln.thread is not None
    ln.thread.join(timeout_s)
    assert not ln.thread.is_alive(), "the service did not end after the internal error"


def _assert_faulted(ln: Line, aborts: Aborts, caplog: pytest.LogCaptureFixture) -> None:
    assert ln.service.exit_code == 1 and ln.service.state == State.STOPPED
    assert aborts.n >= 1 and ln.plc.received.fault
    (record,) = [r for r in caplog.records if getattr(r, "event", "") == "internal_error"]
    assert record.exc_info is not None and "boom" in str(record.exc_info[1])
    store = Store.read_only(ln.service.paths.db)
    try:
        (alarm,) = store.active_alarms(code="internal_error")
        states = [e["data"]["to"] for e in store.events("state")]
    finally:
        store.close()
    assert alarm["priority"] == "urgent" and "RuntimeError: boom" in alarm["message"]
    assert states[-1] == "fault"


def test_an_error_in_the_loop_faults_the_cell_and_ends_with_status_1(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ln = make_line(tmp_path)
    aborts = Aborts(ln)
    real = ln.service.cycle.run_window
    windows = [0]

    def run_window(n: int) -> Any:
        windows[0] += 1
        if windows[0] == 2:
            raise RuntimeError("boom")
        return real(n)

    ln.service.cycle.run_window = run_window  # type: ignore[method-assign,assignment]
    caplog.set_level(logging.ERROR, logger="rvis")
    try:
        ln.start()
        _run_to_exit(ln)
        _assert_faulted(ln, aborts, caplog)
    finally:
        ln.close()

    again = make_line(tmp_path)  # the supervisor's restart: FAULT until an operator resets
    try:
        again.start()
        again.wait(lambda e: e["event"] == "state" and e["to"] == "fault")
        assert again.service.request("reset", {}, uid=0).result(20)["ok"]
        again.windows(1)
        assert again.service.state in (State.IDLE, State.MEASURING)
    finally:
        again.close()


def test_an_error_in_a_connection_thread_faults_the_cell_too(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ln = make_line(tmp_path)
    aborts = Aborts(ln)

    def status() -> dict[str, Any]:
        raise RuntimeError("boom")

    caplog.set_level(logging.ERROR, logger="rvis")
    try:
        with serving(ln.service):
            ln.start()
            ln.windows(1)
            ln.service.status = status  # type: ignore[method-assign]
            from app.line.control import ControlClient

            client_error: list[BaseException] = []

            def ask() -> None:
                try:
                    with ControlClient(ln.service.paths.socket, timeout_s=10.0) as c:
                        c.request("status")
                except Exception as exc:  # the connection ends without a reply
                    client_error.append(exc)

            t = threading.Thread(target=ask)
            t.start()
            t.join(20)
            _run_to_exit(ln)
        _assert_faulted(ln, aborts, caplog)
        assert client_error  # the client learns its request failed
    finally:
        ln.close()
