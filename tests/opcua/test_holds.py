"""Holds that issue 39's guard let through (issue 51 item 3), each at the fresh clients' own
address or from a few addresses of its own: a peer holding secure channels that never create a
session, sessions created and never activated, or activated anonymous sessions (16 from one
address, 64 from four: the session cap) locks no fresh client out; and the refusal log is
limited overall, not only per address (19 addresses write at most 20 lines in 30 s)."""

from __future__ import annotations

import asyncio
import re
from types import SimpleNamespace

import pytest

from app.line.opcua import admission, refusals
from tests.opcua.conftest import Records
from tests.opcua.peers import (
    Holder,
    SessionHolder,
    hello_message,
    open_channel_message,
    read_state,
)

HOLDERS = 80  # connections the hostile peer holds (more than the server takes)
CLIENTS = 20  # fresh clients, one after another, during a hold
AT_LEAST = 19  # of them must get through (95 %)
FOUR_HOSTS = tuple(f"127.0.0.{i}" for i in range(2, 6))  # 4 x 16 = 64: the server full
CLIENT_TIMEOUT_S = 5.0


def fresh_clients(url: str, n: int) -> int:
    """How many of `n` fresh clients, one after another, connect, create and activate a
    session and read the machine's state."""

    async def all_of() -> int:
        ok = 0
        for _ in range(n):
            try:
                await read_state(url, timeout_s=CLIENT_TIMEOUT_S)
            except Exception:  # refused, closed, timed out: one that did not get through
                continue
            ok += 1
        return ok

    return asyncio.run(all_of())


def test_a_peer_holding_secure_channels_locks_nobody_out(own_url: str) -> None:
    """80 sockets at the clients' own address (127.0.0.1), each a Hello and an
    OpenSecureChannel, then nothing (before: 77 of 96 fresh clients got through)."""
    send = hello_message(own_url) + open_channel_message()
    with Holder(own_url, HOLDERS, send=send) as holder:
        assert holder.evicted.wait(30)  # full: the server closes its channels for new ones
        ok = fresh_clients(own_url, CLIENTS)
    assert ok >= AT_LEAST, f"{ok} of {CLIENTS} fresh clients got through"


def test_sessions_created_and_never_activated_lock_nobody_out(own_url: str) -> None:
    with SessionHolder(own_url, HOLDERS, activate=False) as holder:
        assert holder.evicted.wait(30)
        ok = fresh_clients(own_url, CLIENTS)
    assert ok >= AT_LEAST, f"{ok} of {CLIENTS} fresh clients got through"


@pytest.mark.parametrize("sources", [("127.0.0.1",), FOUR_HOSTS], ids=["one", "four"])
def test_activated_sessions_lock_nobody_out(own_url: str, sources: tuple[str, ...]) -> None:
    """16 anonymous sessions activated from the clients' own address (the peer's cap), or 64
    from four other addresses (the server's), then idle (before: 0 of 14 and 0 of 10 fresh
    clients got through): each fresh client's session takes the place of the least recently
    active session of that address, or of the address with the most sessions."""
    with SessionHolder(own_url, admission.MAX_PER_PEER * len(sources), sources=sources) as holder:
        assert holder.full.wait(60)
        ok = fresh_clients(own_url, CLIENTS // 2)
        assert ok == CLIENTS // 2, f"{ok} of {CLIENTS // 2} fresh clients got through"
        assert holder.evicted.wait(10)  # its idle sessions made room


def test_the_refusal_log_is_limited_overall(
    monkeypatch: pytest.MonkeyPatch, records: Records
) -> None:
    """19 addresses refused 10 times a second each for 30 s (before: 57 lines, three per
    address): at most 20 lines, and they account for every refusal but those of the last 20 s
    (a host's count since its last line, and the summary of the window not over yet)."""
    now = [1000.0]
    monkeypatch.setattr(refusals, "time", SimpleNamespace(monotonic=lambda: now[0]))
    log = refusals.RefusalLog()
    hosts = [f"192.0.2.{i}" for i in range(1, 20)]
    refused = 0
    while now[0] < 1030.0:
        for host in hosts:
            log.note(host, "BadTimeout: no Hello within 2 s", "deadline")
            refused += 1
        now[0] += 0.1
    lines = [r.getMessage() for r in records.records if "refused" in r.getMessage()]
    assert 0 < len(lines) <= 20, len(lines)
    told = 0
    for line in lines:
        more = re.search(r"\((\d+) more refused from", line)
        summary = re.search(r"(\d+) refused in all", line)
        told += int(summary.group(1)) if summary else 1 + (int(more.group(1)) if more else 0)
    assert any("refused in all" in line for line in lines)  # the hosts beyond, summed up
    assert refused - 2 * 10 * 19 * refusals.LOG_EVERY_S <= told <= refused
