"""`rvis run --sim` with `[opcua] enabled`: the service as its own process publishes over OPC UA
from its start to its SIGTERM, says where it listens in its log, and its subscribers see it
stop (`stopped`, MachineryItemState NotAvailable: the last values they receive) before the
server drops their session."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client

from app.line.opcua.space import NS_MACHINERY
from tests.opcua.conftest import CELL, Catcher, child, machine_node
from tests.ops.conftest import ServiceProcess
from tests.ports import free_port


def _start(tmp_path: Path) -> tuple[ServiceProcess, str]:
    url = f"opc.tcp://127.0.0.1:{free_port()}/rvis"
    cell = tmp_path / "cell.toml"
    cell.write_text(CELL + f'enabled = true\nendpoint = "{url}"\n', encoding="utf-8")
    svc = ServiceProcess(tmp_path / "state", cell)
    line = svc.wait_log(lambda r: "OPC UA server listening" in r.get("msg", ""), 60.0)
    assert url in line["msg"]
    svc.wait_ready()
    return svc, url


async def _read(url: str) -> tuple[str, int]:
    """ServiceState, and Windows once it counts the first window (the log says the window
    was used a moment before the OPC UA process has its status: a subscription waits for
    the value, with a deadline, instead of racing it)."""
    async with Client(url) as client:
        m = await machine_node(client)
        state = await (await child(client, m, "ServiceState")).read_value()
        catcher = Catcher()
        sub = await client.create_subscription(20, catcher)
        await sub.subscribe_data_change(await child(client, m, "Windows"))
        windows = 0
        async with asyncio.timeout(30.0):
            while windows < 1:
                _, _, val, _ = await catcher.changes.get()
                windows = int(val or 0)
        return state, windows


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_rvis_run_publishes_over_opcua(tmp_path: Path) -> None:
    svc, url = _start(tmp_path)
    try:
        state, windows = asyncio.run(_read(url))
        assert state in ("idle", "measuring") and windows >= 1
    finally:
        code = svc.stop()
    assert code == 0, svc.stderr


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_subscribers_see_the_service_stop(tmp_path: Path) -> None:
    """SIGTERM to the service's process group: a subscriber (20 ms publishing), listening
    until the server drops its session, receives ServiceState `stopped` and
    MachineryItemState NotAvailable as the last values before the drop."""
    svc, url = _start(tmp_path)
    seen: list[tuple[str, Any]] = []
    dropped: list[bool] = []  # the server dropped the session (not the client)
    failed: list[BaseException] = []
    subscribed = threading.Event()

    async def watch() -> None:
        client = Client(url, timeout=5)
        client.session_timeout = 5000
        await client.connect()

        def gone() -> bool:  # the server closed the connection
            protocol = client.uaclient.protocol
            return protocol is None or protocol.is_closed

        try:
            m = await machine_node(client)
            ns_m = await client.get_namespace_index(NS_MACHINERY)
            state = await child(client, m, "ServiceState")
            current = await m.get_child([f"{ns_m}:MachineryItemState", "0:CurrentState"])
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            await sub.subscribe_data_change([state, current])
            subscribed.set()

            def note(node: Any, value: Any) -> None:
                seen.append(("state", value) if node == state else ("item", value.Text))

            async with asyncio.timeout(60):
                while not gone():
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(0.05):
                            _, node, value, _ = await handler.changes.get()
                            note(node, value)
            await asyncio.sleep(0.5)  # sleep-ok: a grace for notifications sent before the drop
            while not handler.changes.empty():
                _, node, value, _ = handler.changes.get_nowait()
                note(node, value)
            dropped.append(True)
        except BaseException as exc:
            failed.append(exc)
            raise
        finally:
            with contextlib.suppress(Exception):  # the server has gone
                await client.disconnect()

    watcher = threading.Thread(target=lambda: asyncio.run(watch()))
    watcher.start()
    try:
        assert subscribed.wait(30)
        svc.wait_windows(1)
    finally:
        code = svc.stop()
    watcher.join(60)
    assert code == 0, svc.stderr
    assert not failed and dropped == [True], (failed, seen)
    # the service was ready when subscribed: NotAvailable comes only with the stop, and the
    # stop is the last thing the subscriber heard before the server went
    states = [v for k, v in seen if k == "state"]
    items = [v for k, v in seen if k == "item"]
    assert states[-1] == "stopped" and states.index("stopped") == len(states) - 1, seen
    assert items[-1] == "NotAvailable" and items.index("NotAvailable") == len(items) - 1, seen
