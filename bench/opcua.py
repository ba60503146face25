"""Benchmarks of the OPC UA server (issue 21): the CPU of the waiting service with and without
it (and with a subscribed client), and the latency from a service event to the OPC UA client's
notification.

    nice -n 5 .venv/bin/python bench/opcua.py [--repeats 30] [--idle-s 5] [--rounds 3]

The service runs with the real clock on bench/line.py's in-process fakes (10 ms poll), the OPC
UA server on loopback in its own process (fed by the service's threads; its CPU counted with
the service's), the client (asyncua) in another process, so that its CPU is not the
service's. Latencies use CLOCK_MONOTONIC, shared by the two processes: from the
service's `bus.emit` of the event (the instant `rvis status` would show it) to the client's
handler. Events: `state` (pause / resume -> ServiceState data change), `alarm` and
`alarm_cleared` (the PLC heartbeat frozen and restored -> AlarmConditionType events), at two
publishing intervals of the client. Medians, p95 and max of the repeats; the idle CPU as the
median of `--rounds` rounds, each configuration measured in every round (alternating), and its
ratio to the service alone in the same run.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import queue
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.threads import limit_blas_threads

limit_blas_threads()

import numpy as np

from app.config.line import OpcUaSettings
from app.line.opcua.server import OpcUaServer
from app.line.opcua.space import NS_MACHINERY, NS_RVIS
from app.line.service import Service
from bench.line import BenchPlc, _service, print_table
from drivers.plc import PlcInputs, encode_inputs

MACHINE = "bench-cell"
POLL_S = 0.01


class FreezablePlc(BenchPlc):
    """The bench PLC whose heartbeat can stop (the service alarms plc_heartbeat)."""

    frozen = False

    def _read_input_words(self) -> tuple[int, int]:
        if not self.frozen:
            self.beat = (self.beat + 1) & 0xFFFF
        return encode_inputs(PlcInputs(self.window_bit, True, self.beat))


class Stamps:
    """The monotonic time of each `bus.emit` of the watched kinds (a wrapper on the bus)."""

    def __init__(self, svc: Service, kinds: tuple[str, ...]) -> None:
        self.q: queue.Queue[tuple[str, dict[str, Any], float]] = queue.Queue()
        emit = svc.bus.emit

        def stamped(kind: str, data: dict[str, Any], **kw: Any) -> None:
            t = time.monotonic()
            emit(kind, data, **kw)
            if kind in kinds:
                self.q.put((kind, data, t))

        svc.bus.emit = stamped  # type: ignore[method-assign]

    def next(self, kind: str, timeout_s: float = 10.0) -> float:
        deadline = time.monotonic() + timeout_s
        while True:
            k, _, t = self.q.get(timeout=max(0.01, deadline - time.monotonic()))
            if k == kind:
                return t


class ClientProcess:
    """`bench/opcua.py --client URL --interval MS` in its own process: its notifications."""

    def __init__(self, url: str, interval_ms: float) -> None:
        argv = [sys.executable, __file__, "--client", url, "--interval", str(interval_ms)]
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self.wait(lambda r: r["k"] == "ready", 60.0)

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            self.lines.put(json.loads(raw))

    def wait(self, pred: Callable[[dict[str, Any]], bool], timeout_s: float = 10.0) -> float:
        deadline = time.monotonic() + timeout_s
        while True:
            r = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            if pred(r):
                return float(r.get("t", 0.0))

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


async def client_main(url: str, interval_ms: float) -> None:
    """The client: ServiceState and Windows data changes, alarm events, as JSON lines."""
    from asyncua import Client, ua

    def out(**r: Any) -> None:
        print(json.dumps({"t": time.monotonic(), **r}, default=str), flush=True)

    class Handler:
        def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
            out(k="data", v=val)

        def event_notification(self, event: Any) -> None:
            out(k="event", code=event.ConditionName, active=getattr(event, "ActiveState/Id"))

    async with Client(url) as client:
        ns = await client.get_namespace_index(NS_RVIS)
        ns_m = await client.get_namespace_index(NS_MACHINERY)
        machine = await client.nodes.objects.get_child([f"{ns_m}:Machines", f"{ns}:{MACHINE}"])
        nodes = [n for n in await machine.get_children() if await n.read_node_class() == 2]
        sub = await client.create_subscription(interval_ms, Handler())
        await sub.subscribe_data_change(nodes, sampling_interval=0)
        await sub.subscribe_events(client.nodes.server, ua.ObjectIds.AlarmConditionType)
        out(k="ready")
        await asyncio.Event().wait()


@contextmanager
def service(
    opcua: bool, plc: BenchPlc | None = None
) -> Iterator[tuple[Service, str, OpcUaServer | None]]:
    """The waiting service in a thread (and its OPC UA server); the endpoint URL."""
    port = _free_port()
    url = f"opc.tcp://127.0.0.1:{port}/rvis"
    settings = OpcUaSettings(enabled=opcua, endpoint=url, machine_name=MACHINE)
    with tempfile.TemporaryDirectory() as tmp:
        svc, plc, robot = _service(
            Path(tmp), POLL_S, plc, opcua=settings, line_heartbeat_timeout_s=0.05
        )
        server = OpcUaServer(svc).start() if opcua else None
        thread = threading.Thread(target=svc.run)
        thread.start()
        try:
            yield svc, url, server
        finally:
            svc.stop()
            thread.join()
            if server is not None:
                server.stop()
            robot.close()
            plc.close()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def _thread_cpu_s(prefix: str) -> float:
    """CPU seconds so far of this process's threads whose name starts with `prefix` (Linux)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for t in threading.enumerate():
        if t.name.startswith(prefix) and t.native_id is not None:
            fields = Path(f"/proc/self/task/{t.native_id}/stat").read_text().rsplit(")", 1)[1]
            utime, stime = fields.split()[11:13]
            total += (int(utime) + int(stime)) / tick
    return total


def _process_cpu_s(pid: int | None) -> float:
    """CPU seconds so far of another process (the OPC UA server's; 0 when none)."""
    if pid is None:
        return 0.0
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_share(seconds: float, server_pid: int | None = None) -> tuple[float, float]:
    """CPU time per wall second over `seconds`: the service's process, and the OPC UA server
    (its threads in the service's process and its own process)."""
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    u0 = _thread_cpu_s("rvis-opcua") + _process_cpu_s(server_pid)
    time.sleep(seconds)
    r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    u1 = _thread_cpu_s("rvis-opcua") + _process_cpu_s(server_pid)
    process = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return process / (t1 - t0), (u1 - u0) / (t1 - t0)


def idle_cpu(idle_s: float, rounds: int) -> dict[str, list[tuple[float, float]]]:
    names = ("alone", "+ OPC UA server", "+ server + 1 client")
    out: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
    for _ in range(rounds):
        for name in out:
            with service(opcua=name != "alone") as (_svc, url, server):
                client = ClientProcess(url, 100.0) if "client" in name else None
                time.sleep(1.0)  # past the start
                out[name].append(cpu_share(idle_s, server.pid if server else None))
                if client is not None:
                    client.close()
    return out


def latencies(repeats: int, interval_ms: float) -> dict[str, list[float]]:
    plc = FreezablePlc()
    out: dict[str, list[float]] = {"state": [], "alarm": [], "alarm_cleared": []}
    rng = np.random.default_rng(int(interval_ms))
    with service(opcua=True, plc=plc) as (svc, url, _server):
        client = ClientProcess(url, interval_ms)
        stamps = Stamps(svc, tuple(out))
        try:
            phase = lambda: time.sleep(rng.uniform(0.0, interval_ms / 1000))  # noqa: E731
            for k in range(repeats):  # each change at a random phase of the publishing cycle
                phase()
                cmd, word = ("pause", "paused") if k % 2 == 0 else ("resume", "idle")
                svc.request(cmd).result(10)
                t0 = stamps.next("state")
                out["state"].append(client.wait(lambda r, w=word: r.get("v") == w) - t0)
                phase()
                plc.frozen = True
                t0 = stamps.next("alarm")
                t1 = client.wait(lambda r: r.get("code") == "plc_heartbeat" and r["active"])
                out["alarm"].append(t1 - t0)
                phase()
                plc.frozen = False
                t0 = stamps.next("alarm_cleared")
                t1 = client.wait(lambda r: r.get("code") == "plc_heartbeat" and not r["active"])
                out["alarm_cleared"].append(t1 - t0)
        finally:
            client.close()
    return out


def _ms(values: list[float]) -> str:
    v = 1000 * np.asarray(values)
    return (
        f"median {np.median(v):.1f}, p95 {np.percentile(v, 95):.1f}, max {v.max():.1f} (n={len(v)})"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--repeats", type=int, default=40)
    p.add_argument("--idle-s", type=float, default=5.0)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--intervals", type=float, nargs="+", default=[20.0, 100.0])
    p.add_argument("--client", help=argparse.SUPPRESS)
    p.add_argument("--interval", type=float, default=100.0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.client:
        asyncio.run(client_main(args.client, args.interval))
        return 0
    rows: list[tuple[str, str, str]] = []
    for interval in args.intervals:
        lat = latencies(args.repeats, interval)
        for kind, what in (
            ("state", "ServiceState data change"),
            ("alarm", "alarm raised -> AlarmConditionType event"),
            ("alarm_cleared", "alarm cleared -> inactive event"),
        ):
            rows.append(
                (
                    f"{kind} event -> {what}, {interval:g} ms publishing [ms]",
                    _ms(lat[kind]),
                    "<= 100",
                )
            )
    cpu = idle_cpu(args.idle_s, args.rounds)
    alone = statistics.median(p for p, _ in cpu["alone"])
    for name, values in cpu.items():
        med = statistics.median(p for p, _ in values)
        threads = statistics.median(u for _, u in values)
        rows.append(
            (
                f"idle CPU, service {name}, 10 ms poll [% of a core]",
                f"{100 * med:.2f} (x{med / alone:.2f} of alone; rounds "
                + ", ".join(f"{100 * p:.2f}" for p, _ in values)
                + (f"; the OPC UA server {100 * threads:.3f})" if name != "alone" else ")"),
                "",
            )
        )
    print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
