"""The bodies' results over OPC UA (issue 49 item 4): a client subscribed to
BodyResultEventType receives exactly one event per body the service measured, in body order,
its fields those the database holds (bodies, body_evaluations, body_values); the machine's
LastBody variables read the last body's, typed, the deviation with its unit; a restarted server
process publishes them again. The simulated line (seed 3, the simulated part type) measures a
body in each clamp period; H03 moves 1 mm from the third body on (a tool change at the body
shop), so that OK and NOK bodies both pass. Waits on notifications with timeouts, never
sleeps."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import signal
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from asyncua import Client, Node

from app.config import load_cell
from app.line.launch import hold_state
from app.line.opcua.feed import TICK, FeedQueue
from app.line.opcua.results import FIELDS, SEVERITY_NOK, SEVERITY_OK, message
from app.line.opcua.server import OpcUaServer
from app.line.opcua.space import NS_RVIS
from app.line.statedir import StateDir
from app.line.store import Store
from app.sim.line_run import SimulatedLineRun
from app.sim.part import ensure_features
from tests.opcua.conftest import CELL, Catcher, child, machine_node, own_server

WINDOWS = 4  # a body each clamp period: four bodies
MMT = int.from_bytes(b"MMT", "big")  # UNECE's millimetre, as EUInformation's UnitId
TYPES = {var.name: var.vtype for var in FIELDS}


@dataclass
class BodiesLine:
    run: SimulatedLineRun
    server: OpcUaServer
    url: str
    state: StateDir


@pytest.fixture(scope="module")
def bodies_line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BodiesLine]:
    root = tmp_path_factory.mktemp("opcua-bodies")
    (root / "cell.toml").write_text(CELL, encoding="utf-8")
    cfg = load_cell(root / "cell.toml")
    shift = dataclasses.replace(cfg.simline, shift_feature="H03", shift_at_body=2, shift_mm=1.0)
    cfg = dataclasses.replace(cfg, simline=shift)
    state = StateDir(root / "state")
    with hold_state(state.root):
        ensure_features(state.root, cfg)
        with SimulatedLineRun(cfg, state.root, seed=3, geometric=True) as run:
            url, settings = own_server(run)
            with OpcUaServer(run.service, settings) as server:
                yield BodiesLine(run, server, url, state)


def _worst(values: list[dict[str, Any]]) -> tuple[str, float]:
    """The stored value furthest out of its tolerance, as a share of it, and its deviation."""
    best: tuple[float, str, float] | None = None
    for v in values:
        if v["measured_mm"] is None:
            continue
        dev = v["measured_mm"] - v["nominal_mm"]
        lo, hi = v["lower_mm"] - v["nominal_mm"], v["upper_mm"] - v["nominal_mm"]
        share = abs(dev - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
        if best is None or share > best[0]:
            best = (share, f"{v['feature']}.{v['characteristic']}", dev)
    assert best is not None
    return best[1], best[2]


def _stored(state: StateDir) -> list[dict[str, Any]]:
    """Each stored body's result as the OPC UA fields name it, oldest first."""
    store = Store.read_only(state.db)
    try:
        out = []
        for b in store.bodies():
            worst, deviation = _worst(store.body_values(int(b["id"])))
            out.append(
                {
                    "BodyId": str(b["body_id"]), "Ok": bool(b["ok"]), "NokCount": b["n_nok"],
                    "UndecidedCount": b["n_undecided"], "NotMeasuredCount": b["n_not_measured"],
                    "WorstCharacteristic": worst, "WorstDeviationMm": deviation,
                    "ParamsVersion": b["params_version"],
                }
            )  # fmt: skip
        return out
    finally:
        store.close()


def _same(got: dict[str, Any], want: dict[str, Any]) -> None:
    assert got.keys() == want.keys()
    for name, value in want.items():
        if isinstance(value, float):
            assert got[name] == pytest.approx(value, abs=1e-9), name
        else:
            assert got[name] == value, name


async def _last_body_node(client: Client) -> Node:
    return await child(client, await machine_node(client), "LastBody")


async def _last_body(client: Client) -> tuple[dict[str, Any], dict[str, Any]]:
    """LastBody's values and, per variable, its type and (WorstDeviationMm) its unit."""
    last = await _last_body_node(client)
    values, types = {}, {}
    for name in TYPES:
        node = await child(client, last, name)
        dv = await node.read_data_value()
        assert dv.StatusCode.is_good(), (name, dv.StatusCode)
        values[name] = dv.Value.Value
        types[name] = await node.read_data_type_as_variant_type()
    unit = await (await child(client, last, "WorstDeviationMm", "0:EngineeringUnits")).read_value()
    types["unit"] = (unit.UnitId, unit.DisplayName.Text)
    return values, types


def test_one_result_event_per_body_in_order_equal_to_the_database(
    bodies_line: BodiesLine,
) -> None:
    line = bodies_line
    told: list[dict[str, Any]] = []

    async def scenario() -> tuple[list[Any], dict[str, Any], dict[str, Any]]:
        async with Client(line.url) as client:
            ns = await client.get_namespace_index(NS_RVIS)
            etype = await client.nodes.base_event_type.get_child(f"{ns}:BodyResultEventType")
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            await sub.subscribe_events(await machine_node(client), etype)
            await asyncio.to_thread(line.run.run_windows, WINDOWS, None, told.append)
            last_id = str([e for e in told if e["event"] == "body"][-1]["body_id"])
            events: list[Any] = []
            while not events or events[-1].BodyId != last_id:  # (each awaited 10 s at most)
                events.append((await handler.event(lambda e: True))[1])
            values, types = await _last_body(client)
            return events, values, types

    events, values, types = asyncio.run(scenario())
    stored = _stored(line.state)
    bodies = [e for e in told if e["event"] == "body"]
    assert len(stored) == len(bodies) >= 3  # (a body each period: WINDOWS)
    # one event per body, in order, each the database's
    assert [e.BodyId for e in events] == [b["BodyId"] for b in stored]
    for event, want, sent in zip(events, stored, bodies, strict=True):
        _same({name: getattr(event, name) for name in TYPES}, want)
        assert event.Severity == (SEVERITY_OK if want["Ok"] else SEVERITY_NOK)
        verdict = "OK" if want["Ok"] else "NOK"
        assert event.Message.Text.startswith(f"body {want['BodyId']} {verdict}")
        assert f"worst {want['WorstCharacteristic']} {want['WorstDeviationMm']:+.2f} mm" in (
            event.Message.Text
        )
        assert abs(event.Time.timestamp() - sent["t"]) < 1e-3  # the service's clock
        unit = getattr(event, "WorstDeviationMm/EngineeringUnits")
        assert (unit.UnitId, unit.DisplayName.Text) == (MMT, "mm")
    assert {e.Ok for e in events} == {True, False}  # the shifted feature's bodies are NOK
    assert any(e.WorstCharacteristic.startswith("H03.") for e in events if not e.Ok)
    # the last body's summary, typed, the deviation in mm
    _same(values, stored[-1])
    assert types == {**TYPES, "unit": (MMT, "mm")}

    # a restarted server process publishes the last body again (the service holds meanwhile)
    first = line.server.pid
    assert first is not None
    line.server.restarted.clear()
    os.kill(first, signal.SIGKILL)
    assert line.server.restarted.wait(60) and line.server.wait_ready(60)

    async def read_again() -> dict[str, Any]:
        """LastBody once the new process has it (it is given the last body after it listens):
        read at each of its data changes until it is."""
        async with Client(line.url) as client:
            nodes = [await child(client, await _last_body_node(client), n) for n in TYPES]
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            await sub.subscribe_data_change(nodes)
            async with asyncio.timeout(30):
                while True:
                    dvs = [await node.read_data_value(False) for node in nodes]
                    if all(dv.StatusCode.is_good() for dv in dvs):
                        values = {n: dv.Value.Value for n, dv in zip(TYPES, dvs, strict=True)}
                        if values["BodyId"] == stored[-1]["BodyId"]:
                            return values
                    await handler.changes.get()

    _same(asyncio.run(read_again()), stored[-1])


def test_body_results_are_kept_each_in_order_by_the_feed() -> None:
    """Body events are never merged into the status ticks; when kept events fill the queue
    the oldest goes, counted."""
    q = FeedQueue(100)
    for n in (1, 2):
        q.offer({"event": "window", "t": float(n)})
        q.offer({"event": "body", "t": float(n), "body_id": n})
    q.offer({"event": "state", "t": 3.0})
    batch, _ = q.take()
    assert [(m["event"], m.get("body_id")) for m in batch] == [
        (TICK, None),
        ("body", 1),
        (TICK, None),
        ("body", 2),
        (TICK, None),
    ]
    full = FeedQueue(2)
    for n in (1, 2, 3):
        full.offer({"event": "body", "t": float(n), "body_id": n})
    batch, _ = full.take()
    assert [m["body_id"] for m in batch] == [2, 3] and full.lost == 1


def test_the_result_message() -> None:
    nok: dict[str, Any] = {"body_id": 100012, "ok": False, "n_nok": 2, "n_undecided": 0}
    worst = {"characteristic": "H03.X", "deviation_mm": 0.4149, "decision": "nonconforming"}
    assert message({**nok, "worst": worst}) == (
        "body 100012 NOK: 2 characteristics out, worst H03.X +0.41 mm"
    )
    ok = {
        "body_id": "B0100001",
        "ok": True,
        "n_undecided": 1,
        "worst": {**worst, "deviation_mm": -0.2},
    }
    assert message(ok) == "body B0100001 OK: 1 undecided, worst H03.X -0.20 mm"
    missing: dict[str, Any] = {"body_id": None, "ok": False, "n_not_measured": 3, "worst": {}}
    assert message({**missing, "withdrawn": "the PLC took it back"}) == (
        "body (no id) NOK: 3 not measured (withdrawn: the PLC took it back)"
    )
