"""The control socket against a running service: mode 0660, status, commands and their errors,
the audit log with the peer's uid (SO_PEERCRED), and the event stream."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from app.line.control import ControlClient, ControlServer
from app.line.states import State
from tests.line.helpers import Line, make_line


@pytest.fixture()
def served(tmp_path: Path) -> Iterator[tuple[Line, Path]]:
    ln = make_line(tmp_path)
    path = tmp_path / "rvis.sock"
    with ControlServer(ln.service, path):
        ln.start().wait(lambda e: e["event"] == "state" and e["to"] == "idle")
        try:
            yield ln, path
        finally:
            ln.close()
    assert not path.exists()


def test_socket_mode_and_status(served: tuple[Line, Path]) -> None:
    _ln, path = served
    assert stat.S_IMODE(path.stat().st_mode) == 0o660
    with ControlClient(path) as c:
        reply = c.request("status")
    assert reply["id"] == 1 and reply["ok"] is True
    assert reply["state"] in ("idle", "measuring") and reply["params_version"] == 1
    assert reply["schedule"]["slots"] == 24
    cal = reply["calibration"]
    assert (cal["version"], cal["pending"], cal["rms_mm"]) == (1, None, None)
    assert cal["applied_utc"] is not None  # version 1: the starting parameters, applied now
    step = "waiting for a window" if reply["state"] == "idle" else "measuring in the window"
    assert reply["pending"] is None and reply["step"] == step
    assert reply["window"]["line_running"] is True
    assert isinstance(reply["window"]["heartbeat_alive"], bool)


def test_commands_are_executed_and_audited_with_the_peer_uid(served: tuple[Line, Path]) -> None:
    ln, path = served
    with ControlClient(path) as c:
        assert c.request("pause") == {"id": 1, "ok": True, "message": "paused", "state": "paused"}
        assert ln.service.state == State.PAUSED
        ln.plc.wait_edges(2)  # paused: windows pass unused
        windows = ln.service.decision.counters["windows"]
        ln.plc.wait_edges(1)
        assert ln.service.decision.counters["windows"] == windows
        assert c.request("resume")["ok"]
        bad = c.request("ack", {"alarm": 99})
        assert bad == {"id": 3, "ok": False, "error": "no unacknowledged alarm 99"}
        assert c.request("ack", {"alarm": "x"})["error"] == "'alarm' must be an integer"
        assert c.request("reset")["error"] == "nothing to reset in state idle"
        assert c.request("fly")["error"] == "unknown command 'fly'"
    actions = ln.service.store.actions()
    assert [(a["cmd"], a["ok"]) for a in actions] == [
        ("pause", True),
        ("resume", True),
        ("ack", False),
        ("ack", False),
        ("reset", False),
    ]
    assert {a["uid"] for a in actions} == {os.getuid()}
    assert actions[2]["args"] == {"alarm": 99}


def test_bad_request_lines_get_an_error_and_the_connection_stays(
    served: tuple[Line, Path],
) -> None:
    _, path = served
    with ControlClient(path) as c:
        c.sock.sendall(b"this is not json\n")
        assert c.read()["error"].startswith("bad request")
        c.sock.sendall(b'{"id": 5, "cmd": "status", "args": [1]}\n')
        assert c.read() == {
            "id": None,
            "ok": False,
            "error": 'bad request: "args" must be an object',
        }
        assert c.request("status")["ok"]
        c.sock.sendall(b'{"id": 9, "cmd": "ack", "alarm": 99}\n')  # arguments next to cmd
        assert c.read() == {"id": 9, "ok": False, "error": "no unacknowledged alarm 99"}


def test_subscribe_streams_the_events(served: tuple[Line, Path]) -> None:
    _ln, path = served
    with ControlClient(path) as sub, ControlClient(path) as c:
        assert sub.request("subscribe") == {"id": 1, "ok": True}
        kinds = set()
        while "measurement" not in kinds or "window" not in kinds:
            kinds.add(sub.read()["event"])
        c.request("pause")
        while (ev := sub.read())["event"] != "operator":
            pass
        assert ev["cmd"] == "pause" and ev["uid"] == os.getuid()


def test_an_alarm_is_acknowledged_and_shelved_with_a_reason(served: tuple[Line, Path]) -> None:
    ln, path = served
    ln.plc.heartbeat_frozen = True
    alarm = ln.wait(lambda e: e["event"] == "alarm")
    with ControlClient(path) as c:
        assert c.request("ack", {"alarm": alarm["id"]})["ok"]
        assert c.request("shelve", {"alarm": alarm["id"]})["error"] == "shelving needs a 'reason'"
        reply = c.request("shelve", {"alarm": alarm["id"], "reason": "PLC update", "minutes": 5})
        assert reply["ok"], reply
        (shown,) = c.request("status")["alarms"]
    assert (shown["code"], shown["state"]) == ("plc_heartbeat", "shelved")
    (row,) = ln.service.store.active_alarms()
    assert row["acked_uid"] == os.getuid() and row["shelve_reason"] == "PLC update"
    assert row["shelved_until"] - row["t_raised"] == pytest.approx(300.0, abs=60.0)
