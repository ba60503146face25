"""The tracker side-car peer is as strict as docs/tracker-sidecar.md: every malformed request is
code 2 "bad request", an unknown command code 1; and the driver's requests pass that check."""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from typing import Any

import pytest

from drivers.tracker_tcp import TcpTracker
from fakes.tracker_service import E_BAD_REQUEST, E_UNKNOWN_COMMAND, TrackerService
from fakes.world import StaticWorld


@pytest.fixture
def svc(world: StaticWorld) -> Iterator[TrackerService]:
    with TrackerService(world, seed=3) as s:
        yield s


@pytest.fixture
def conn(svc: TrackerService) -> Iterator[Any]:
    sock = socket.create_connection(("127.0.0.1", svc.port), timeout=2.0)
    file = sock.makefile("rb")

    def ask(raw: bytes) -> dict[str, Any]:
        sock.sendall(raw + b"\n")
        reply: dict[str, Any] = json.loads(file.readline())
        return reply

    yield ask
    file.close()
    sock.close()


@pytest.mark.parametrize(
    ("request_line", "echo"),
    [
        (b"{not json", None),
        (b"[1, 2]", None),
        (b'{"cmd": "status"}', None),  # no id
        (b'{"id": "7", "cmd": "status"}', None),  # id not an integer
        (b'{"id": true, "cmd": "status"}', None),
        (b'{"id": 4}', 4),  # no cmd
        (b'{"id": 5, "cmd": "hello"}', 5),  # no protocol
        (b'{"id": 6, "cmd": "hello", "protocol": "rvis-tracker/2"}', 6),
        (b'{"id": 7, "cmd": "measure", "target": "S1"}', 7),  # no timeout_s
        (b'{"id": 8, "cmd": "measure", "target": "S1", "timeout_s": -1}', 8),
        (b'{"id": 9, "cmd": "measure", "target": "S1", "timeout_s": "30"}', 9),
        (b'{"id": 10, "cmd": "measure", "timeout_s": 30}', 10),  # no target
    ],
)
def test_malformed_requests_are_bad_requests(
    conn: Any, request_line: bytes, echo: int | None
) -> None:
    reply = conn(request_line)
    assert reply["id"] == echo and reply["ok"] is False
    assert reply["error"]["code"] == E_BAD_REQUEST and reply["error"]["message"]


def test_unknown_command_and_valid_requests(conn: Any) -> None:
    assert conn(b'{"id": 1, "cmd": "fly"}')["error"]["code"] == E_UNKNOWN_COMMAND
    hello = conn(b'{"id": 2, "cmd": "hello", "protocol": "rvis-tracker/1"}')
    assert hello["ok"] and hello["protocol"] == "rvis-tracker/1"
    m = conn(b'{"id": 3, "cmd": "measure", "target": "S1", "timeout_s": 30}')
    assert m["ok"] and m["id"] == 3 and m["target"] == "S1"


def test_the_driver_speaks_the_documented_requests(svc: TrackerService) -> None:
    with TcpTracker("127.0.0.1", svc.port, timeout_s=1.0) as tracker:
        tracker.measure("S2", timeout_s=12.5)
    measure = [r for r in svc.requests if r["cmd"] == "measure"]
    assert measure == [
        {"id": measure[0]["id"], "cmd": "measure", "target": "S2", "timeout_s": 12.5}
    ]
    assert {"cmd": "hello", "protocol": "rvis-tracker/1"}.items() <= svc.requests[0].items()
