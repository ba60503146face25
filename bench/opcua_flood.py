"""Flood bench of the OPC UA server (issue 29): can a network peer slow the cycle or grow the
service's memory?

    nice -n 5 .venv/bin/python bench/opcua_flood.py [--root SOURCE_TREE] [--flood-s 60]

`rvis run --sim --geometric` (the simulated line, x60: a 60 s clamp cycle in 1 s) with
`[opcua] enabled` on a loopback port, run from `--root` (default: this tree; give another
checkout, e.g. main's, for a before/after). Three phases: quiet (`--quiet-s`), flood
(`--flood-s`: `--peers` processes, each connecting again and again and sending, in turn, a
Hello whose header claims 4 GB then streaming 64 KiB blocks, a malformed Hello then streaming,
a message of no OPC UA type, and a valid Hello followed by an OpenSecureChannel chunk claiming
1 GB then streaming; each connection streams until the server closes it or for 5 s), and after
(`--after-s`). Per phase: the service's windows, overruns and withdrawn windows (its status
counters), its process's CPU and resident memory (VmRSS, sampled every 0.5 s; the OPC UA
server's own process, when it has one, apart), `rvis status` answered through the control
socket (the round trip, every 0.2 s) and as a command (`python -m app status --json`, one
after another, 1 s apart), and what the peers did. The peers run at nice 10 (on a real
network they are on other machines; here they share the 2 cores). Every loop is bounded in
time and count and stops by itself; the service gets SIGTERM at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import resource
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
PAGE = os.sysconf("SC_PAGE_SIZE")
TICK = os.sysconf("SC_CLK_TCK")
MAX_CONNECTIONS_PER_PEER = 200_000
CONNECTION_S = 5.0
BLOCK = bytes(65536)


# -- the peers -------------------------------------------------------------------------------
def _hello(url: str, claimed: int | None = None) -> bytes:
    endpoint = url.encode()
    body = struct.pack("<IIIIIi", 0, 65535, 65535, 0, 0, len(endpoint)) + endpoint
    return struct.pack("<3scI", b"HEL", b"F", claimed or 8 + len(body)) + body


def _variants(url: str) -> list[tuple[str, bytes, bool]]:
    """(name, first bytes, whether a Hello's Acknowledge is awaited first)."""
    return [
        ("hello claiming 4 GB", _hello(url, 0xFFFFFFF0), False),
        ("malformed hello", struct.pack("<3scIIIIIIi", b"HEL", b"F", 64, 0, 1, 1, 0, 0, -7), False),
        ("no OPC UA type", b"GETF" + struct.pack("<I", 1 << 30), False),
        ("OPN chunk claiming 1 GB", b"OPNF" + struct.pack("<I", 1 << 30) + bytes(8), True),
    ]


def peer(url: str, seconds: float, index: int) -> dict[str, Any]:
    """One flooding peer: connections until `seconds` passed (bounded in count too)."""
    host, port = url.split("//")[1].split("/")[0].rsplit(":", 1)
    variants = _variants(url)
    out = {"connections": 0, "bytes_sent": 0, "err_replies": 0, "refused_connect": 0}
    deadline = time.monotonic() + seconds
    k = index
    while time.monotonic() < deadline and out["connections"] < MAX_CONNECTIONS_PER_PEER:
        _name, first, needs_ack = variants[k % len(variants)]
        k += 1
        try:
            s = socket.create_connection((host, int(port)), timeout=2)
        except OSError:
            out["refused_connect"] += 1
            time.sleep(0.01)
            continue
        out["connections"] += 1
        with s:
            try:
                s.settimeout(2)
                if needs_ack:
                    s.sendall(_hello(url))
                    s.recv(28)
                s.sendall(first)
                out["bytes_sent"] += len(first)
                until = min(deadline, time.monotonic() + CONNECTION_S)
                while time.monotonic() < until:
                    s.sendall(BLOCK)
                    out["bytes_sent"] += len(BLOCK)
            except OSError:
                pass  # closed by the server
            try:
                s.settimeout(0.5)
                if s.recv(8)[:3] == b"ERR":
                    out["err_replies"] += 1
            except OSError:
                pass
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out["cpu_s"] = round(usage.ru_utime + usage.ru_stime, 1)
    return out


# -- the service -----------------------------------------------------------------------------
class Service:
    """`rvis run --sim --geometric` from `root` with OPC UA on `url`; its log lines."""

    def __init__(self, root: Path, tmp: Path, url: str, opcua: str = "") -> None:
        """opcua: more lines of the [opcua] section (a security policy, ...)."""
        cell = tmp / "cell.toml"
        cell.write_text(
            f'[opcua]\nenabled = true\nendpoint = "{url}"\nmachine_name = "flood-cell"\n{opcua}',
            encoding="utf-8",
        )
        self.state = tmp / "state"
        self.root = root
        env = {**os.environ, "PYTHONPATH": str(root), "PYTHONDONTWRITEBYTECODE": "1"}
        self.env = env
        argv = [sys.executable, "-m", "app", "run", "--sim", "--geometric", "--cell", str(cell)]
        self.proc = subprocess.Popen(
            [*argv, "--state-dir", str(self.state)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=root,
            env=env,
            start_new_session=True,
        )
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        threading.Thread(target=self._read_err, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            try:
                self.lines.put(json.loads(raw))
            except ValueError:
                self.lines.put({"raw": raw.decode(errors="replace")})

    def _read_err(self) -> None:
        assert self.proc.stderr is not None
        for raw in self.proc.stderr:
            self.stderr.append(raw.decode(errors="replace"))

    def wait_log(self, pred: Callable[[dict[str, Any]], bool], timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            line = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            if pred(line):
                return

    def drain(self) -> list[dict[str, Any]]:
        out = []
        while True:
            try:
                out.append(self.lines.get_nowait())
            except queue.Empty:
                return out

    def status_rtt(self) -> tuple[float, dict[str, Any]]:
        """One status request on the control socket: its round trip [s] and the reply."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(30)
            s.connect(str(self.state / "rvis.sock"))
            t0 = time.perf_counter()
            s.sendall(b'{"id": 1, "cmd": "status"}\n')
            data = b""
            while not data.endswith(b"\n"):
                chunk = s.recv(1 << 20)
                if not chunk:
                    break
                data += chunk
            return time.perf_counter() - t0, json.loads(data)

    def status_command_s(self) -> float:
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "app", "status", "--json", "--state-dir", str(self.state)],
            cwd=self.root,
            env=self.env,
            capture_output=True,
            timeout=60,
            check=True,
        )
        return time.perf_counter() - t0

    def children(self) -> list[int]:
        """The service's OPC UA server process (none when the server runs inside it)."""
        out = []
        for task in Path(f"/proc/{self.proc.pid}/task").iterdir():
            with_children = task / "children"
            if with_children.exists():
                out += [int(p) for p in with_children.read_text().split()]
        return [p for p in out if b"opcua" in _cmdline(p)]

    def stop(self) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            return self.proc.wait(10)


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def cpu_s(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / TICK


class Phase:
    """Samples of one phase: RSS (service, server process), status round trips and commands."""

    def __init__(self, svc: Service, name: str) -> None:
        self.svc, self.name = svc, name
        self.rss: list[float] = []
        self.child_rss: list[float] = []
        self.rtt: list[float] = []
        self.command: list[float] = []
        self.counters0: dict[str, int] = {}
        self.counters1: dict[str, int] = {}
        self.cpu0 = self.cpu1 = 0.0
        self.child_cpu0 = self.child_cpu1 = 0.0
        self.t0 = self.t1 = 0.0

    def run(
        self, seconds: float, during: Callable[[], None] | None = None, commands: bool = True
    ) -> None:
        """Sample for `seconds`, `during()` called at the start; `rvis status` run as a command
        every second unless not `commands` (a Python start-up each: CPU of its own)."""
        svc = self.svc
        pid = svc.proc.pid
        kids = svc.children()
        self.counters0 = svc.status_rtt()[1]["counters"]
        self.cpu0, self.t0 = cpu_s(pid), time.monotonic()
        self.child_cpu0 = sum(cpu_s(k) for k in kids)
        if during is not None:
            during()
        stop = threading.Event()

        def run_commands() -> None:
            while not stop.wait(1.0):
                self.command.append(svc.status_command_s())

        worker = threading.Thread(target=run_commands, daemon=True)
        if commands:
            worker.start()
        deadline = self.t0 + seconds
        next_rss = self.t0
        while (now := time.monotonic()) < deadline:
            self.rtt.append(svc.status_rtt()[0])
            if now >= next_rss:
                self.rss.append(rss_mb(pid) or 0.0)
                self.child_rss.append(sum(rss_mb(k) or 0.0 for k in kids))
                next_rss += 0.5
            stop.wait(0.2)
        stop.set()
        if commands:
            worker.join(60)
        self.cpu1, self.t1 = cpu_s(pid), time.monotonic()
        self.child_cpu1 = sum(cpu_s(k) for k in kids)
        self.counters1 = svc.status_rtt()[1]["counters"]

    def row(self) -> dict[str, Any]:
        d = {k: self.counters1[k] - self.counters0.get(k, 0) for k in self.counters1}
        ms = [1000 * x for x in self.rtt]
        return {
            "phase": self.name,
            "seconds": round(self.t1 - self.t0, 1),
            "windows": d.get("windows"),
            "overruns": d.get("overruns"),
            "withdrawn": d.get("withdrawn"),
            "service CPU [% of a core]": round(
                100 * (self.cpu1 - self.cpu0) / (self.t1 - self.t0), 1
            ),
            "server process CPU [%]": round(
                100 * (self.child_cpu1 - self.child_cpu0) / (self.t1 - self.t0), 1
            ),
            "service RSS start/max/end [MB]": (
                f"{self.rss[0]:.0f} / {max(self.rss):.0f} / {self.rss[-1]:.0f}"
            ),
            "server process RSS max [MB]": round(max(self.child_rss), 0) if self.child_rss else 0,
            "status round trip median/p95/max [ms]": (
                f"{statistics.median(ms):.1f} / {_p95(ms):.1f} / {max(ms):.1f} (n={len(ms)})"
            ),
            "rvis status command median/max [s]": (
                f"{statistics.median(self.command):.2f} / {max(self.command):.2f}"
                f" (n={len(self.command)})"
                if self.command
                else "-"
            ),
        }


def _p95(values: list[float]) -> float:
    return sorted(values)[max(0, round(0.95 * len(values)) - 1)]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--root", type=Path, default=HERE.parent, help="the source tree to run")
    p.add_argument("--peers", type=int, default=4)
    p.add_argument("--quiet-s", type=float, default=30.0)
    p.add_argument("--flood-s", type=float, default=60.0)
    p.add_argument("--after-s", type=float, default=20.0)
    p.add_argument("--json", type=Path, help="also write the rows here")
    p.add_argument("--peer", help=argparse.SUPPRESS)
    p.add_argument("--peer-index", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.peer:
        os.nice(10)
        print(json.dumps(peer(args.peer, args.flood_s, args.peer_index)), flush=True)
        return 0
    url = f"opc.tcp://127.0.0.1:{_free_port()}/rvis"
    with tempfile.TemporaryDirectory() as tmp:
        svc = Service(args.root.resolve(), Path(tmp), url)
        peers: list[subprocess.Popen[str]] = []
        try:
            svc.wait_log(lambda r: "OPC UA server listening" in str(r.get("msg", "")), 120)
            for _ in range(5):
                svc.wait_log(lambda r: r.get("event") == "window", 60)
            quiet = Phase(svc, "quiet")
            quiet.run(args.quiet_s)

            def start_peers() -> None:
                for i in range(args.peers):
                    peers.append(
                        subprocess.Popen(
                            [sys.executable, __file__, "--peer", url, "--peer-index", str(i),
                             "--flood-s", str(args.flood_s)],
                            stdout=subprocess.PIPE,
                            text=True,
                        )
                    )  # fmt: skip

            flood = Phase(svc, f"flood ({args.peers} peers)")
            flood.run(args.flood_s, start_peers)
            done = [json.loads(q.communicate(timeout=60)[0]) for q in peers]
            after = Phase(svc, "after")
            after.run(args.after_s)
        finally:
            for q in peers:
                if q.poll() is None:
                    q.kill()
            code = svc.stop()
        logs = svc.drain()
    rows = [quiet.row(), flood.row(), after.row()]
    total = {k: round(sum(d[k] for d in done), 1) for k in done[0]} if done else {}
    tracebacks = sum("Traceback" in line for line in svc.stderr)
    refusals = [r for r in logs if "refused" in str(r.get("msg", ""))]
    for key in rows[0]:
        print(f"{key:<42}" + "".join(f"{r[key]!s:<40}" for r in rows))
    print(f"peers: {total}")
    print(f"service exit status {code}; log lines with 'refused': {len(refusals)};"
          f" tracebacks on stderr: {tracebacks} ({len(svc.stderr)} stderr lines)")  # fmt: skip
    for line in svc.stderr[:5]:
        print(f"  stderr: {line.rstrip()[:160]}")
    for r in refusals[:3]:
        print(f"  log: {str(r.get('msg'))[:160]}")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "peers": total}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
