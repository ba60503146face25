"""The server is out of the cycle's way: it runs in its own process (restarted when it dies,
the service untouched), and a peer's oversized or malformed message gets the protocol's ERR
message and one log line (never a traceback) and its connection closed at once, while the
other clients are served."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest
from asyncua import Client, ua

from app.errors import InputError
from app.line.opcua import server as server_module
from app.line.opcua.server import OpcUaServer, _close_pipes
from app.sim.line_run import SimulatedLineRun
from tests.opcua.conftest import Records, Servers, child, machine_node
from tests.opcua.peers import error_code, hello_message
from tests.ports import free_port


def exchange(
    url: str, data: bytes, stream_s: float = 0.0, hello: bool = False
) -> tuple[bytes, float]:
    """Send `data` (after a Hello and its Acknowledge when `hello`; then zeros for up to
    `stream_s`, as a flood would) and read until the server closes: what it answered after
    the Acknowledge and how long the connection lasted."""
    host, port = url.split("//")[1].split("/")[0].split(":")
    t0 = time.monotonic()
    with socket.create_connection((host, int(port)), timeout=10) as s:
        if hello:
            s.sendall(hello_message(url))
            ack = b""
            while len(ack) < 28:  # the Acknowledge: header and five UInt32
                ack += s.recv(28 - len(ack))
            assert ack[:4] == b"ACKF", ack
        s.sendall(data)
        junk = bytes(65536)
        deadline = t0 + stream_s
        try:
            while time.monotonic() < deadline:
                s.sendall(junk)
        except OSError:
            pass  # closed by the server: what it sent is still readable
        answer = b""
        try:
            while chunk := s.recv(65536):
                answer += chunk
        except OSError:
            pass  # a reset after the ERR
    return answer, time.monotonic() - t0


def test_oversized_and_malformed_messages_get_err_and_are_closed(
    servers: Servers, records: Records
) -> None:
    url = servers.read_only
    # a header claiming 4 GB, then data streamed: closed at the header, not after 30 s
    answer, lasted = exchange(url, hello_message(url, size_claimed=0xFFFFFFF0), stream_s=3.0)
    assert error_code(answer) == ua.StatusCodes.BadTcpMessageTooLarge and lasted < 5.0
    assert records.refused.wait(10)
    # a message type a server does not receive, a secure message before any Hello
    for data in (b"XYZF" + struct.pack("<I", 16) + bytes(8), b"MSGF" + struct.pack("<I", 40)):
        answer, _ = exchange(url, data + bytes(32))
        assert error_code(answer) == ua.StatusCodes.BadTcpMessageTypeInvalid
    # a Hello whose body cannot be decoded (its URL length beyond the message)
    bad = struct.pack("<3scI", b"HEL", b"F", 40) + struct.pack("<IIIIIi", 0, 1, 1, 0, 0, 9999)
    answer, _ = exchange(url, bad + bytes(8))
    assert error_code(answer) == ua.StatusCodes.BadDecodingError
    # after the Hello and its Acknowledge, a chunk beyond the negotiated buffer
    answer, _ = exchange(url, b"OPNF" + struct.pack("<I", 1 << 20) + bytes(64), hello=True)
    assert error_code(answer) == ua.StatusCodes.BadTcpMessageTooLarge

    async def read() -> str:  # the server still serves its clients
        async with Client(url) as client:
            node = await child(client, await machine_node(client), "ServiceState")
            value: str = await node.read_value()
            return value

    assert asyncio.run(read()) in ("idle", "measuring", "paused")
    lines = [r.getMessage() for r in records.records]
    assert any("BadTcpMessageTooLarge" in m for m in lines), lines
    assert not any("Traceback" in r.getMessage() or r.exc_info for r in records.records)
    # one line per peer host per 10 s: the six refusals made one or two lines
    assert sum("refused" in m for m in lines) <= 2


def test_the_server_process_is_restarted_when_it_dies(line: SimulatedLineRun) -> None:
    """The new server process publishes the service as it is: paused (nothing changes it
    meanwhile, so the truth is known), with the windows it has used."""
    url = f"opc.tcp://127.0.0.1:{free_port()}/rvis"
    settings = dataclasses.replace(line.service.settings.opcua, enabled=True, endpoint=url)

    async def read() -> tuple[str, int]:
        async with Client(url) as client:
            m = await machine_node(client)
            state = await (await child(client, m, "ServiceState")).read_value()
            windows = await (await child(client, m, "Windows")).read_value()
            return state, windows

    events = line.service.bus.subscribe()
    try:  # a window used before the pause: the count published is not a fresh server's 0
        if line.service.status()["counters"]["windows"] < 1:
            while events.get(timeout=30)["event"] != "window":
                pass
    finally:
        line.service.bus.unsubscribe(events)
    with OpcUaServer(line.service, settings) as server:
        first = server.pid
        assert first is not None and first != os.getpid()
        paused = line.service.request("pause").result(30)
        try:
            assert paused["ok"] and paused["state"] == "paused", paused
            truth = line.service.status()
            os.kill(first, signal.SIGKILL)
            assert server.restarted.wait(60)  # the watcher saw it die and started another
            assert server.wait_ready(60)
            assert server.pid not in (first, None) and server.restarts == 1
            state, windows = asyncio.run(read())
        finally:
            assert line.service.request("resume").result(30)["ok"]
    assert truth["state"] == "paused" and truth["counters"]["windows"] >= 1
    assert (state, windows) == ("paused", truth["counters"]["windows"])
    assert line.service.state.value != "fault"


def test_a_start_that_times_out_leaves_no_second_reader(
    line: SimulatedLineRun, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A (re)start whose server process does not listen in time: the process is killed and
    the start's reader of its pipe has ended when the error comes, so the watcher that reads
    the pipe next (and restarts it) is its only reader."""
    url = f"opc.tcp://127.0.0.1:{free_port()}/rvis"
    settings = dataclasses.replace(line.service.settings.opcua, enabled=True, endpoint=url)
    server = OpcUaServer(line.service, settings)  # not started: its start is driven here

    def mute() -> None:  # a server process that never says it listens
        server._proc = subprocess.Popen(
            [sys.executable, "-c", "import sys; sys.stdin.buffer.read()"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )

    monkeypatch.setattr(server, "_spawn", mute)
    monkeypatch.setattr(server_module, "START_TIMEOUT_S", 0.5)
    try:
        server._spawn()
        with pytest.raises(InputError, match=r"not listening after 0\.5 s"):
            server._await_start()
        assert server._proc is not None and server._proc.poll() is not None  # killed
        readers = [t for t in threading.enumerate() if t.name == "rvis-opcua-start"]
        assert not readers
    finally:
        line.service.bus.unsubscribe(server._events)
        if server._proc is not None:
            server._kill()
            _close_pipes(server._proc)
