"""The OPC UA server against the simulated line: one service for the package (`rvis run --sim
--geometric` in this process, its control socket served, a window every 0.5 s), two OPC UA
servers on it (read-only, acknowledging), asyncua clients that browse by name. Every test
leaves the service running normally. Tests wait on notifications with timeouts, never sleep."""

from __future__ import annotations

import asyncio
import logging
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, Node, ua

from app.config import load_cell
from app.config.line import OpcUaSettings
from app.line.launch import hold_state, serving
from app.line.opcua.server import OpcUaServer
from app.line.opcua.space import NS_MACHINERY, NS_RVIS
from app.sim.line_run import SimulatedLineRun
from tests.ports import free_port

# 60 s clamp cycles paced at x120 (the clients watch it live): a window every 0.5 s; no warm-up:
# the cell temperature is constant; the PLC polled every 2 s of line time, not every second (a
# poll is a Modbus exchange). The line runs while every test of the package runs: at x300 and a
# poll a second it cost the package 2:35 of CPU, now 2:02-2:07, in the same wall time
CELL = """
[simline]
scale = 120.0
warmup_k = 0.0
poll_s = 2.0
[opcua]
machine_name = "cell-7"
serial_number = "SN-0007"
product_instance_uri = "urn:plant-a:body-shop:cell-7"
"""
MACHINE = "cell-7"


def own_server(run: SimulatedLineRun, **changes: Any) -> tuple[str, OpcUaSettings]:
    """A loopback endpoint on a free port and the run's [opcua] settings for a server there
    (enabled; `changes` on top)."""
    url = f"opc.tcp://127.0.0.1:{free_port()}/rvis"
    opcua = replace(run.service.settings.opcua, enabled=True, endpoint=url, **changes)
    return url, opcua


@pytest.fixture(scope="package")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimulatedLineRun]:
    root = tmp_path_factory.mktemp("opcua")
    (root / "cell.toml").write_text(CELL, encoding="utf-8")
    cfg = load_cell(root / "cell.toml")
    state = root / "state"
    with (
        hold_state(state),
        SimulatedLineRun(cfg, state, seed=3, geometric=True, pace=cfg.simline.scale) as run,
        serving(run.service),
    ):
        run.start_service()
        yield run


@pytest.fixture(scope="module")
def own_url(line: SimulatedLineRun) -> Iterator[str]:
    """An OPC UA server of the module's own (the package's servers are left in peace)."""
    url, settings = own_server(line)
    with OpcUaServer(line.service, settings):
        yield url


@dataclass(frozen=True)
class Servers:
    """Two OPC UA servers on the module's service: read-only and one that allows acks."""

    read_only: str
    acking: str


@pytest.fixture(scope="package")
def servers(line: SimulatedLineRun) -> Iterator[Servers]:
    urls = Servers(*(f"opc.tcp://127.0.0.1:{free_port()}/rvis" for _ in range(2)))
    base = replace(line.service.settings.opcua, enabled=True)
    with (
        OpcUaServer(line.service, replace(base, endpoint=urls.read_only)),
        OpcUaServer(line.service, replace(base, endpoint=urls.acking, allow_ack=True)),
    ):
        yield urls


async def machine_node(client: Client) -> Node:
    """Objects/Machines/<machine>, by browse names."""
    ns = await client.get_namespace_index(NS_RVIS)
    ns_m = await client.get_namespace_index(NS_MACHINERY)
    node: Node = await client.nodes.objects.get_child([f"{ns_m}:Machines", f"{ns}:{MACHINE}"])
    return node


async def child(client: Client, parent: Node, *names: str) -> Node:
    """A descendant by rvis browse names ("ns:Name" when another namespace)."""
    ns = await client.get_namespace_index(NS_RVIS)
    path = [n if ":" in n else f"{ns}:{n}" for n in names]
    node: Node = await parent.get_child(path)
    return node


class Catcher:
    """asyncua subscription handler: every data change and event with its arrival time."""

    def __init__(self) -> None:
        self.changes: asyncio.Queue[tuple[float, Node, Any, ua.DataValue]] = asyncio.Queue()
        self.events: asyncio.Queue[tuple[float, Any]] = asyncio.Queue()

    def datachange_notification(self, node: Node, val: Any, data: Any) -> None:
        dv = data.monitored_item.Value
        self.changes.put_nowait((time.monotonic(), node, val, dv))

    def event_notification(self, event: Any) -> None:
        self.events.put_nowait((time.monotonic(), event))

    async def event(self, pred: Any, timeout_s: float = 10.0) -> tuple[float, Any]:
        """The first event from now on for which pred(event) holds."""
        async with asyncio.timeout(timeout_s):
            while True:
                t, event = await self.events.get()
                if pred(event):
                    return t, event


def state_dir(run: SimulatedLineRun) -> Path:
    return Path(run.service.settings.state_dir)


ROOT = Path(__file__).resolve().parents[2]


def rvis(run: SimulatedLineRun, *args: str) -> str:
    """`rvis ARGS --state-dir <the run's>` as its own process (as an operator would type it);
    its standard output, after asserting it succeeded."""
    command, *rest = args
    out = subprocess.run(
        [sys.executable, "-m", "app", command, "--state-dir", str(state_dir(run)), *rest],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


class Records(logging.Handler):
    """The OPC UA log records of this process (the server process's are logged here)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []
        self.refused = threading.Event()
        self._more = threading.Condition()

    def emit(self, record: logging.LogRecord) -> None:
        with self._more:
            self.records.append(record)
            self._more.notify_all()
        if "refused" in record.getMessage():
            self.refused.set()

    def wait_for(self, done: Callable[[list[str]], bool], timeout_s: float) -> bool:
        """Whether done(the messages so far) holds within `timeout_s` (looked at each record)."""
        with self._more:
            return self._more.wait_for(
                lambda: done([r.getMessage() for r in self.records]), timeout_s
            )


@pytest.fixture
def records() -> Iterator[Records]:
    handler = Records()
    logger = logging.getLogger("rvis.line.opcua")
    old = logger.level
    logger.setLevel(logging.DEBUG)
    logger.addHandler(handler)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
