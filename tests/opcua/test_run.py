"""`rvis run --sim` with `[opcua] enabled`: the service as its own process publishes over OPC UA
from its start to its SIGTERM, and says where it listens in its log."""

from __future__ import annotations

import asyncio
from pathlib import Path

from asyncua import Client

from tests.opcua.conftest import CELL, child, free_port, machine_node
from tests.ops.conftest import ServiceProcess


async def _read(url: str) -> tuple[str, int]:
    async with Client(url) as client:
        m = await machine_node(client)
        state = await (await child(client, m, "ServiceState")).read_value()
        windows = await (await child(client, m, "Windows")).read_value()
        return state, windows


def test_rvis_run_publishes_over_opcua(tmp_path: Path) -> None:
    url = f"opc.tcp://127.0.0.1:{free_port()}/rvis"
    cell = tmp_path / "cell.toml"
    cell.write_text(CELL + f'enabled = true\nendpoint = "{url}"\n', encoding="utf-8")
    svc = ServiceProcess(tmp_path / "state", cell)
    try:
        line = svc.wait_log(lambda r: "OPC UA server listening" in r.get("msg", ""), 60.0)
        assert url in line["msg"]
        svc.wait_ready()
        state, windows = asyncio.run(_read(url))
        assert state in ("idle", "measuring") and windows >= 1
    finally:
        code = svc.stop()
    assert code == 0, svc.stderr
