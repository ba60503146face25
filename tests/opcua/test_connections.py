"""No peer can lock the port (issue 39 item 1): a peer holding more connections than the server
takes, and reopening each one the server closes, evicts its own idle connections, never a
well-behaved client that got further; connections that send no Hello, open no secure channel
or activate no session are closed at their deadlines; the secure-only endpoint opens no
unencrypted channel; and every refusal, asyncua's own records included, makes at most one log
line per peer per 10 s."""

from __future__ import annotations

import asyncio
import logging
import math
import re
import shutil
import socket
import time
from collections import Counter
from pathlib import Path

import pytest
from asyncua import ua

from app.line.opcua import refusals
from app.line.opcua.server import OpcUaServer
from app.line.statedir import StateDir
from app.sim.line_run import SimulatedLineRun
from tests.opcua.conftest import Records, own_server
from tests.opcua.peers import (
    Holder,
    client_certificate,
    error_code,
    hello_message,
    open_channel_message,
    read_state,
    read_until_closed,
    split_url,
)

CLIENTS = 5  # fresh clients during each attack
HOLDERS = 80  # connections the hostile peer holds (more than the server takes)
OTHER_HOSTS = tuple(f"127.0.0.{i}" for i in range(2, 7))  # 5 x 16 = 80: the server full


def refusal_lines(records: Records) -> Counter[str]:
    """The refusal log lines by the peer host they name."""
    return host_lines([r.getMessage() for r in records.records])


def host_lines(messages: list[str]) -> Counter[str]:
    hosts: Counter[str] = Counter()
    for m in messages:
        found = re.match(r"OPC UA connection from (\S+) refused", m)
        if found:
            hosts[found.group(1)] += 1
    return hosts


def named(messages: list[str]) -> set[str]:
    """The hosts the refusal lines name: each in a line of its own or in a summary of them."""
    hosts = set(host_lines(messages))
    for m in messages:
        summary = re.match(r"OPC UA connections refused from .* in all \((.*)\)$", m)
        if summary:
            hosts |= set(summary.group(1).split(" and ")[0].split(", "))
    return hosts


def reads(url: str, n: int, secured: dict[str, Path] | None = None) -> list[str]:
    """`n` fresh clients one after another (connect, session, read): what each read."""

    async def all_of() -> list[str]:
        return [await read_state(url, **(secured or {})) for _ in range(n)]  # type: ignore[arg-type]

    return asyncio.run(all_of())


def test_a_peer_holding_and_reopening_connections_locks_nobody_out(
    own_url: str, records: Records
) -> None:
    t0 = time.monotonic()
    # five hosts fill the server (16 each), the rest of their 80 sockets reopened at once
    with Holder(own_url, HOLDERS, sources=OTHER_HOSTS) as holder:
        assert holder.evicted.wait(30)  # full: the server closes connections to take new ones
        assert set(reads(own_url, CLIENTS)) <= {"idle", "measuring", "paused"}
    # one peer at the clients' own address, a Hello on each socket
    with Holder(own_url, HOLDERS, send=hello_message(own_url)) as holder:
        assert holder.evicted.wait(30)
        assert len(reads(own_url, CLIENTS)) == CLIENTS
    # every holder had connections evicted (the hosts beyond 3 a window in a summary after it)
    holders = {"127.0.0.1", *OTHER_HOSTS}
    assert records.wait_for(lambda m: named(m) == holders, refusals.LOG_EVERY_S + 5)
    lines = refusal_lines(records)
    assert all("evicted" in m for m in [r.getMessage() for r in records.records] if host_lines([m]))
    at_most = 1 + math.ceil((time.monotonic() - t0) / refusals.LOG_EVERY_S)
    assert lines and max(lines.values()) <= at_most, lines
    assert not any("max_connections" in r.getMessage() for r in records.records)


def test_connections_that_do_not_get_on_are_closed_at_their_deadlines(own_url: str) -> None:
    with socket.create_connection(split_url(own_url)) as silent:
        assert error_code(read_until_closed(silent)) == ua.StatusCodes.BadTimeout
    with socket.create_connection(split_url(own_url)) as hello_only:
        hello_only.sendall(hello_message(own_url))
        answer = read_until_closed(hello_only)
    assert answer[:4] == b"ACKF"
    assert error_code(answer[28:]) == ua.StatusCodes.BadTimeout


def test_asyncua_records_of_a_peer_are_counted_and_rate_limited(records: Records) -> None:
    quiet = refusals.QuietAsyncua()
    before = refusals.REFUSALS.counts["asyncua"]
    name = "asyncua.server.binary_server_asyncio"
    refusing = "Refusing connection from %s: at max_connections=%s"
    for port in range(1000):
        record = logging.LogRecord(
            name, logging.WARNING, __file__, 1, refusing, (("192.0.2.7", port), 64), None
        )
        assert not quiet.filter(record)
    assert refusals.REFUSALS.counts["asyncua"] - before == 1000
    assert refusal_lines(records)["192.0.2.7"] == 1
    other = [
        logging.LogRecord(name, logging.WARNING, __file__, 1, "Unauthenticated user", (), None)
        for _ in range(100)
    ]
    assert [quiet.filter(r) for r in other].count(True) == 1
    mine = logging.LogRecord("rvis.line.opcua", logging.WARNING, __file__, 1, "x", (), None)
    assert quiet.filter(mine)


def test_the_secure_only_endpoint_opens_no_unencrypted_channel(
    line: SimulatedLineRun, tmp_path: Path
) -> None:
    url, settings = own_server(line, security_policy="Basic256Sha256")
    paths = StateDir(line.service.settings.state_dir)
    cert, key = asyncio.run(client_certificate(tmp_path, "historian"))
    paths.opcua_trusted.mkdir(parents=True, exist_ok=True)
    shutil.copy(cert, paths.opcua_trusted / cert.name)
    secured = {"cert": cert, "key": key, "server_cert": paths.opcua_cert}
    with OpcUaServer(line.service, settings):
        with socket.create_connection(split_url(url)) as s:
            s.sendall(hello_message(url))
            s.sendall(open_channel_message())
            answer = read_until_closed(s)
        assert answer[:4] == b"ACKF"
        assert error_code(answer[28:]) == ua.StatusCodes.BadSecurityPolicyRejected
        with pytest.raises(ua.UaStatusCodeError):  # a client without security: nothing
            asyncio.run(read_state(url))
        # a trusted client under attack
        with Holder(url, HOLDERS, send=hello_message(url)) as holder:
            assert holder.evicted.wait(30)
            assert len(reads(url, 3, secured)) == 3
