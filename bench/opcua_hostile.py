"""Hostile-peer bench of the OPC UA port (issue 39 item 7, issue 51 item 3): can a peer without
credentials lock well-behaved clients out, flood the service's log or take its CPU and memory?

    .venv/bin/python bench/opcua_hostile.py [--root SOURCE_TREE] [--quiet-s 30] [--hold-s 30]
                                            [--other-s 15] [--only PHASE,...] [--json FILE]

It runs in a network namespace of its own (tests/netns.py; needs root), whose interface carries
10.39.0.1 (the secured endpoint, "beyond loopback" for the endpoint's rules) and 10.39.0.2 (the
hostile peer's address there): all traffic stays inside. Without a namespace it says so and
runs the secured endpoint on loopback. Two services, one after the other, each `rvis run --sim
--geometric` (x60: a window a second) from `--root` with `[opcua]` enabled
(bench/opcua_flood.py's `Service`):

- loopback (`opc.tcp://127.0.0.1:PORT`, no security): quiet; hold (one peer at 127.0.0.1, the
  clients' own address, holding 80 connections that send nothing and reopening each one the
  server closes, at once); hold with a Hello on each; hold with secure channels (a Hello and an
  OpenSecureChannel on each, then nothing); hold with sessions (80 asyncua sessions created,
  never activated); 16 activated sessions (anonymous, at the clients' address, then idle); 64
  activated sessions from four addresses (127.0.0.2-5, 16 each: the server's cap); garbage
  after the Hello (seeded random bytes); oversized messages (bench/opcua_flood.py's peer:
  headers claiming 4 GB or 1 GB, streamed); a connect storm (connect and close, as fast as one
  process can); 19 addresses (garbage after the Hello from 127.0.0.2-20 in turn: the log);
- secured (`opc.tcp://10.39.0.1:PORT`, Basic256Sha256 Sign & Encrypt, the clients' certificate
  trusted, anonymous sessions allowed): quiet; hold (the peer at 10.39.0.2); hold with secure
  channels (80 sockets, each a Hello and an OpenSecureChannel signed with a self-signed
  certificate the server does not trust).

`--only hold,19 addresses` runs those phases (and quiet) only.

In every phase fresh well-behaved clients (asyncua: connect, secure channel, session, read the
machine's ServiceState, disconnect), one after another 0.5 s apart, 5 s timeout each. Per phase:
their successes and median time; the service's log lines (its standard output's records that are
not events, and its standard error); its CPU and RSS (its OPC UA server process apart); windows
and overruns (its status counters); what the peer did. The attacking peer is a process of its
own at nice 10. Every loop is bounded in time and count and stops by itself.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.line.opcua.admission import MAX_PER_PEER
from bench.opcua_flood import Phase, Service, _free_port
from bench.opcua_flood import peer as oversized_peer
from tests.netns import enter_own_network_namespace
from tests.opcua.peers import (
    Holder,
    SessionHolder,
    basic256sha256,
    client_certificate,
    hello_message,
    open_channel_message,
    read_state,
    read_until_closed,
)

HOLD_CONNECTIONS = 80
FOUR_ADDRESSES = tuple(f"127.0.0.{i}" for i in range(2, 6))
NINETEEN_ADDRESSES = tuple(f"127.0.0.{i}" for i in range(2, 21))
LOOPBACK_PHASES = (
    "hold", "hold with Hello", "hold with secure channels", "hold with sessions",
    "16 activated sessions", "64 activated sessions, 4 addresses", "garbage after Hello",
    "oversized messages", "connect storm", "19 addresses",
)  # fmt: skip
SECURED_PHASES = ("hold", "hold with secure channels")
SHORT_PHASES = ("garbage after Hello", "oversized messages", "connect storm")  # --other-s
MAX_CONNECTIONS = 200_000  # a peer's connections in a phase, at most
CLIENT_GAP_S = 0.5
CLIENT_TIMEOUT_S = 5.0
MAX_CLIENTS = 1000  # fresh clients in a phase, at most
SERVER_ADDRESS, PEER_ADDRESS = "10.39.0.1", "10.39.0.2"
SEED = 39


# -- the hostile peer (a process of its own) ------------------------------------------------
def garbage(url: str, seconds: float, sources: tuple[str, ...]) -> dict[str, Any]:
    """Connections that send a Hello, then seeded random bytes, from each of `sources` in
    turn; each read until closed."""
    rng = random.Random(SEED)
    out = {"connections": 0, "err replies": 0, "addresses": len(sources)}
    deadline = time.monotonic() + seconds
    host, port = url.split("//")[1].split("/")[0].rsplit(":", 1)
    while time.monotonic() < deadline and out["connections"] < MAX_CONNECTIONS:
        source = sources[out["connections"] % len(sources)]
        try:
            with socket.create_connection((host, int(port)), 2, (source, 0)) as s:
                out["connections"] += 1
                s.sendall(hello_message(url) + rng.randbytes(rng.randint(16, 4096)))
                if b"ERRF" in read_until_closed(s, 2.0):
                    out["err replies"] += 1
        except OSError:
            pass
    return out


def storm(url: str, seconds: float, source: str) -> dict[str, Any]:
    """Connect and close, again and again (every other one after a Hello)."""
    out = {"connections": 0, "connect failures": 0}
    deadline = time.monotonic() + seconds
    host, port = url.split("//")[1].split("/")[0].rsplit(":", 1)
    hello = hello_message(url)
    while time.monotonic() < deadline and out["connections"] < MAX_CONNECTIONS:
        try:
            with socket.create_connection((host, int(port)), 2, (source, 0)) as s:
                out["connections"] += 1
                if out["connections"] % 2:
                    s.sendall(hello)
        except OSError:
            out["connect failures"] += 1
    return out


def hold(url: str, seconds: float, source: str, send: bytes) -> dict[str, Any]:
    with Holder(url, HOLD_CONNECTIONS, sources=(source,), send=send) as holder:
        threading.Event().wait(seconds)  # the peer's phase: it holds and reopens meanwhile
    return {
        "connections": holder.opens,
        "closed by the server": holder.closed_by_server,
        "connect failures": holder.connect_failures,
    }


def hold_sessions(
    url: str, seconds: float, sources: tuple[str, ...], count: int, activate: bool
) -> dict[str, Any]:
    t0 = time.monotonic()
    with SessionHolder(url, count, sources=sources, activate=activate) as holder:
        full = holder.full.wait(seconds)
        threading.Event().wait(max(0.0, seconds - (time.monotonic() - t0)))  # held meanwhile
    return {
        "sessions": holder.opens,
        f"all {count} held": "yes" if full else "no",
        "closed by the server": holder.closed_by_server,
        "failed": holder.failures,
    }


def untrusted_channel(url: str, server_cert: Path) -> bytes:
    """A Hello and an OpenSecureChannel (Basic256Sha256) signed with a certificate of its own,
    self-signed, that the server does not trust."""
    with tempfile.TemporaryDirectory() as tmp:
        cert, key = asyncio.run(client_certificate(Path(tmp), "intruder"))
        policy = asyncio.run(basic256sha256(cert, key, server_cert))
    return hello_message(url) + open_channel_message(policy)


def attack(
    kind: str, url: str, seconds: float, source: str, server_cert: Path | None
) -> dict[str, Any]:
    if kind == "hold":
        return hold(url, seconds, source, b"")
    if kind == "hold with Hello":
        return hold(url, seconds, source, hello_message(url))
    if kind == "hold with secure channels":
        opn = hello_message(url) + open_channel_message()
        send = opn if server_cert is None else untrusted_channel(url, server_cert)
        return hold(url, seconds, source, send)
    if kind == "hold with sessions":
        return hold_sessions(url, seconds, (source,), HOLD_CONNECTIONS, activate=False)
    if kind == "16 activated sessions":
        return hold_sessions(url, seconds, (source,), MAX_PER_PEER, activate=True)
    if kind == "64 activated sessions, 4 addresses":
        return hold_sessions(url, seconds, FOUR_ADDRESSES, 4 * MAX_PER_PEER, activate=True)
    if kind == "garbage after Hello":
        return garbage(url, seconds, (source,))
    if kind == "19 addresses":
        return garbage(url, seconds, NINETEEN_ADDRESSES)
    if kind == "oversized messages":
        return oversized_peer(url, seconds, 0)
    if kind == "connect storm":
        return storm(url, seconds, source)
    raise ValueError(kind)


# -- the well-behaved clients ---------------------------------------------------------------
class Clients:
    """Fresh clients one after another until stopped (at most MAX_CLIENTS)."""

    def __init__(self, url: str, secured: dict[str, Path]) -> None:
        self.url, self.secured = url, secured
        self.ok_s: list[float] = []
        self.failed: Counter[str] = Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(3 * CLIENT_TIMEOUT_S + 10)

    def _run(self) -> None:
        while not self._stop.is_set() and len(self.ok_s) + self.failed.total() < MAX_CLIENTS:
            t0 = time.monotonic()
            try:
                kw: Any = self.secured
                asyncio.run(read_state(self.url, timeout_s=CLIENT_TIMEOUT_S, **kw))
                self.ok_s.append(time.monotonic() - t0)
            except Exception as exc:
                self.failed[type(exc).__name__] += 1
            self._stop.wait(CLIENT_GAP_S)

    def summary(self) -> tuple[str, str]:
        n = len(self.ok_s) + self.failed.total()
        rate = f"{len(self.ok_s)} of {n} ({100 * len(self.ok_s) / max(n, 1):.0f} %)"
        if self.failed:
            rate += " " + ", ".join(f"{k} {v}" for k, v in self.failed.most_common())
        ms = f"{1000 * statistics.median(self.ok_s):.0f}" if self.ok_s else "-"
        return rate, ms


# -- a service and its phases ---------------------------------------------------------------
def run_service(
    root: Path, url: str, phases: list[tuple[str, float]], source: str, secure: bool
) -> list[dict[str, Any]]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        extra = 'security_policy = "Basic256Sha256"\nallow_anonymous = true\n' if secure else ""
        svc = Service(root, tmp, url, extra)
        try:
            svc.wait_log(lambda r: "OPC UA server listening" in str(r.get("msg", "")), 180)
            secured = trust_a_client(svc.state / "opcua", tmp) if secure else {}
            for _ in range(5):
                svc.wait_log(lambda r: r.get("event") == "window", 60)
            for kind, seconds in phases:
                rows.append(phase(svc, url, kind, seconds, source, secured))
                print(json.dumps(rows[-1]), flush=True)
        finally:
            code = svc.stop()
        print(f"service exit status {code}", flush=True)
    return rows


def trust_a_client(opcua: Path, tmp: Path) -> dict[str, Path]:
    """A client certificate in the server's trusted/ (read at each connection)."""
    cert, key = asyncio.run(client_certificate(tmp, "bench-client"))
    (opcua / "trusted").mkdir(parents=True, exist_ok=True)
    (opcua / "trusted" / cert.name).write_bytes(cert.read_bytes())
    return {"cert": cert, "key": key, "server_cert": opcua / "server-cert.der"}


def phase(
    svc: Service, url: str, kind: str, seconds: float, source: str, secured: dict[str, Path]
) -> dict[str, Any]:
    clients = Clients(url, secured)
    peer: list[subprocess.Popen[str]] = []

    def begin() -> None:
        svc.drain()
        svc.stderr.clear()
        if kind != "quiet":
            argv = [sys.executable, __file__, "--attack", kind, "--url", url, "--source", source]
            if secured:
                argv += ["--server-cert", str(secured["server_cert"])]
            peer.append(
                subprocess.Popen(
                    [*argv, "--seconds", str(seconds)], stdout=subprocess.PIPE, text=True
                )
            )
        clients.start()

    sampled = Phase(svc, kind)
    sampled.run(seconds, begin, commands=False)
    clients.stop()
    logs = [r for r in svc.drain() if "event" not in r]
    did = json.loads(peer[0].communicate(timeout=120)[0]) if peer else {}
    row = sampled.row()
    rate, ms = clients.summary()
    samples = [m[:240] for r in logs if _opcua(m := str(r.get("msg", r)))]
    return {
        "endpoint": "secured" if secured else "loopback",
        "phase": kind,
        "seconds": row["seconds"],
        "fresh clients ok": rate,
        "client median [ms]": ms,
        "service log lines": len(logs) + len(svc.stderr),
        "of them OPC UA": sum(_opcua(str(r.get("msg", ""))) for r in logs)
        + sum(_opcua(line) for line in svc.stderr),
        "windows, overruns": f"{row['windows']}, {row['overruns']}",
        "service CPU [% of a core]": row["service CPU [% of a core]"],
        "server process CPU [%]": row["server process CPU [%]"],
        "service RSS start/max/end [MB]": row["service RSS start/max/end [MB]"],
        "server process RSS max [MB]": row["server process RSS max [MB]"],
        "the peer": ", ".join(f"{k} {v}" for k, v in did.items() if k != "cpu_s"),
        "log samples": samples[:3] + [m for m in samples[3:] if "more address" in m][:1],
    }


def _opcua(line: str) -> bool:
    return "OPC UA" in line or "asyncua" in line or "opcua" in line


def own_network() -> str | None:
    """None once this process is in a network namespace of its own, with the server's and the
    peer's addresses on its loopback interface (this machine's kernel has neither dummy nor
    veth links; an address outside 127.0.0.0/8 is "beyond loopback" for the endpoint's rules
    all the same: the server must offer a signing-and-encrypting policy); else why not."""
    why = enter_own_network_namespace()
    if why is not None:
        return why
    for address in (SERVER_ADDRESS, PEER_ADDRESS):
        command = ["ip", "addr", "add", f"{address}/32", "dev", "lo"]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            return f"{' '.join(command)}: {done.stderr.strip()}"
    return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--root", type=Path, default=ROOT, help="the source tree to run")
    p.add_argument("--quiet-s", type=float, default=30.0)
    p.add_argument("--hold-s", type=float, default=30.0)
    p.add_argument("--other-s", type=float, default=15.0, help="each of the other attacks")
    p.add_argument("--only", help="these phases only (and quiet), comma-separated")
    p.add_argument("--json", type=Path, help="also write the rows here")
    p.add_argument("--attack", help=argparse.SUPPRESS)
    p.add_argument("--url", help=argparse.SUPPRESS)
    p.add_argument("--source", default="127.0.0.1", help=argparse.SUPPRESS)
    p.add_argument("--server-cert", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, default=0.0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.attack:
        os.nice(10)
        did = attack(args.attack, args.url, args.seconds, args.source, args.server_cert)
        print(json.dumps(did), flush=True)
        return 0
    only = None if args.only is None else {k.strip() for k in args.only.split(",")}
    unknown = (only or set()) - {*LOOPBACK_PHASES, *SECURED_PHASES}
    if unknown:
        p.error(f"no phase {', '.join(sorted(unknown))}")

    def phases(kinds: tuple[str, ...]) -> list[tuple[str, float]]:
        chosen = [k for k in kinds if only is None or k in only]
        seconds = {k: args.other_s if k in SHORT_PHASES else args.hold_s for k in chosen}
        return [("quiet", args.quiet_s), *seconds.items()]

    why = own_network()
    if why is not None:
        print(f"no network namespace of its own ({why}): the secured endpoint on loopback")
    server, source = ("127.0.0.1", "127.0.0.1") if why else (SERVER_ADDRESS, PEER_ADDRESS)
    rows: list[dict[str, Any]] = []
    if len(loopback := phases(LOOPBACK_PHASES)) > 1:
        url = f"opc.tcp://127.0.0.1:{_free_port()}/rvis"
        rows += run_service(args.root.resolve(), url, loopback, "127.0.0.1", secure=False)
    if len(secured := phases(SECURED_PHASES)) > 1:
        url = f"opc.tcp://{server}:{_free_port()}/rvis"
        rows += run_service(args.root.resolve(), url, secured, source, secure=True)
    keys = [k for k in rows[0] if k != "log samples"]
    for key in keys:
        print(f"{key:<32}" + "".join(f"{r[key]!s:<26}" for r in rows))
    for r in rows:
        for line in r["log samples"]:
            print(f"  {r['endpoint']} {r['phase']}: {line}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
