"""The variables by browse name: they follow the simulated line window by window and equal
`rvis status` (read through its socket, in another process), timestamped with the service's
clock; the machine reads as OPC 40001-1 names it."""

from __future__ import annotations

import asyncio
import json
import queue
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import pytest
from asyncua import Client, ua

from app.line.beyond_knock import change_need
from app.line.opcua.space import NS_DI, NS_MACHINERY
from app.sim.line_run import SimulatedLineRun
from tests.opcua.conftest import MACHINE, ROOT, Catcher, Servers, child, machine_node, rvis

#: browse name -> its value in `rvis status --json` (None: no value, BadNoValue)
EXPECTED: dict[str, Callable[[dict[str, Any]], Any]] = {
    "ServiceState": lambda s: s["state"],
    "Step": lambda s: s["step"],
    "CalibrationVersion": lambda s: s["calibration"]["version"],
    "CalibrationRmsMm": lambda s: s["calibration"]["rms_mm"],
    "CalibrationAppliedUtc": lambda s: datetime.fromisoformat(s["calibration"]["applied_utc"]),
    "PendingCalibration": lambda s: s["pending_calibration"] or 0,
    "Windows": lambda s: s["counters"]["windows"],
    "Overruns": lambda s: s["counters"]["overruns"],
    "MeasurementsOk": lambda s: s["measurements"]["ok"],
    "MeasurementsRejected": lambda s: s["measurements"]["rejected"],
    "CellTemperatureC": lambda s: s["cell_temp_c"],
    "ActiveAlarms": lambda s: len(s["alarms"]),
    "SuspectOpen": lambda s: any(r["state"] == "open" for r in s["suspect_intervals"]),
    "SuspectBodies": lambda s: next(
        (json.dumps(r["bodies"]) for r in s["suspect_intervals"][::-1] if r["state"] == "open"),
        None,
    ),
    "SuspectIntervals": lambda s: json.dumps(s["suspect_intervals"]),
}


def rvis_status(run: SimulatedLineRun) -> dict[str, Any]:
    status: dict[str, Any] = json.loads(rvis(run, "status", "--json"))
    return status


def plain(dv: ua.DataValue) -> Any:
    if dv.StatusCode.value == ua.StatusCodes.BadNoValue:
        return None
    assert dv.StatusCode.is_good(), dv.StatusCode
    return dv.Value.Value


async def published(client: Client, spheres: list[str]) -> dict[str, Any]:
    m = await machine_node(client)
    out = {}
    for name in EXPECTED:
        out[name] = plain(await (await child(client, m, name)).read_data_value(False))
    for sphere in spheres:
        for name in ("ResidualMm", "PosteriorRmsMm"):
            node = await child(client, m, "Spheres", sphere, name)
            out[f"{sphere}.{name}"] = plain(await node.read_data_value(False))
    return out


def expected(status: dict[str, Any]) -> dict[str, Any]:
    out = {name: get(status) for name, get in EXPECTED.items()}
    for sphere, seen in status["spheres"].items():
        out[f"{sphere}.ResidualMm"] = seen["residual_mm"]
        out[f"{sphere}.PosteriorRmsMm"] = seen["posterior_rms_mm"]
    return out


def test_variables_follow_the_windows_and_equal_rvis_status(
    line: SimulatedLineRun, servers: Servers
) -> None:
    url = servers.read_only
    events = line.service.bus.subscribe()

    async def check() -> None:
        async with Client(url) as client:
            m = await machine_node(client)
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            windows = await child(client, m, "Windows")
            state = await child(client, m, "ServiceState")
            await sub.subscribe_data_change([windows, state])
            seen: list[int] = []
            async with asyncio.timeout(20):
                while len(seen) < 4:  # the initial value, then three windows
                    _, node, value, _ = await handler.changes.get()
                    if node == windows:
                        seen.append(value)
            assert seen == sorted(seen) and len(set(seen)) == 4, seen

            reply = await asyncio.to_thread(lambda: line.service.request("pause").result(30))
            assert reply["ok"], reply
            async with asyncio.timeout(20):
                while (await state.read_value()) != "paused":
                    await handler.changes.get()
            async with asyncio.timeout(30):  # a calibration may still land while paused
                while True:
                    status = await asyncio.to_thread(rvis_status, line)
                    ours = await published(client, list(status["spheres"]))
                    if expected(status) == ours:
                        break
            assert status["state"] == "paused" and status["counters"]["windows"] >= 3
            assert status["spheres"] and ours["Windows"] == status["counters"]["windows"]

            # timestamped with the service's clock (the simulated line runs ahead of the wall)
            ts = (await state.read_data_value()).SourceTimestamp
            t_paused = next(
                e["t"] for e in _drain(events) if e["event"] == "state" and e["to"] == "paused"
            )
            assert abs(ts.timestamp() - t_paused) < 1.0
            assert ts.timestamp() - time.time() > 60.0

            ns_m = await client.get_namespace_index(NS_MACHINERY)
            current = await m.get_child([f"{ns_m}:MachineryItemState", "0:CurrentState"])
            assert (await current.read_value()).Text == "OutOfService"
            state_id = await current.get_child("0:Id")
            assert await state_id.read_value() == ua.NodeId(5004, ns_m)  # OutOfService
            reply = await asyncio.to_thread(lambda: line.service.request("resume").result(30))
            assert reply["ok"], reply
            async with asyncio.timeout(20):
                while (await current.read_value()).Text not in ("NotExecuting", "Executing"):
                    await handler.changes.get()

    try:
        asyncio.run(check())
    finally:
        line.service.bus.unsubscribe(events)


def _drain(q: queue.Queue[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    while True:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            return out


def test_identification_as_opc_40001(servers: Servers) -> None:
    url = servers.read_only

    async def check() -> dict[str, Any]:
        async with Client(url) as client:
            m = await machine_node(client)
            ns_di = await client.get_namespace_index(NS_DI)
            ident = await m.get_child(f"{ns_di}:Identification")
            values = {}
            for prop in await ident.get_properties():
                dv = await prop.read_data_value()
                name = (await prop.read_browse_name()).Name
                assert dv.SourceTimestamp is not None, name  # the service's clock at the start
                values[name] = dv.Value.Value
            rms = await child(client, m, "CalibrationRmsMm")
            unit = await rms.get_child("0:EngineeringUnits")
            values["unit"] = (await unit.read_value()).DisplayName.Text
            return values

    values = asyncio.run(check())
    assert values["Manufacturer"].Text == "rvis" and values["SerialNumber"] == "SN-0007"
    assert values["ProductInstanceUri"] == "urn:plant-a:body-shop:cell-7"
    printed = subprocess.run(
        [sys.executable, "-m", "app", "--version"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    ).stdout.strip()
    assert f"rvis {values['SoftwareRevision']}" == printed  # what `rvis --version` prints
    assert values["Model"].Text.startswith("RVIS") and values["unit"] == "mm"


def test_a_client_cannot_write(servers: Servers) -> None:
    url = servers.acking  # even where acknowledging is allowed

    async def check() -> None:
        async with Client(url) as client:
            node = await child(client, await machine_node(client), "ServiceState")
            with pytest.raises(ua.UaStatusCodeError):
                await node.write_value(ua.DataValue(ua.Variant("idle", ua.VariantType.String)))

    asyncio.run(check())


def test_the_suspect_interval_variables_of_a_status_reply() -> None:
    """An open suspect interval (a knock, app.line.step) reads as SuspectOpen with its start and
    size; a closed one leaves the start and size without a value."""
    from app.line.opcua.space import VARIABLES, data_value, lookup

    t = datetime.now(UTC)
    closed = {"state": "closed", "start_utc": "2026-11-25T08:00:00+00:00", "size_mm": 0.2}
    opened = {"state": "open", "start_utc": "2026-11-25T09:30:00+00:00", "size_mm": 0.31}
    by_name = {v.name: v for v in VARIABLES}

    def read(name: str, rows: list[dict[str, Any]]) -> Any:
        var = by_name[name]
        return plain(data_value(var, lookup({"suspect_intervals": rows}, var.path), t, None))

    assert read("SuspectOpen", [closed, opened]) is True
    assert read("SuspectStartUtc", [closed, opened]) == datetime(2026, 11, 25, 9, 30, tzinfo=UTC)
    assert read("SuspectSizeMm", [closed, opened]) == 0.31
    assert json.loads(read("SuspectIntervals", [closed, opened])) == [closed, opened]
    assert read("SuspectOpen", [closed]) is False
    assert read("SuspectStartUtc", [closed]) is None and read("SuspectSizeMm", []) is None
    # the bodies measured in the open interval so far (the line PLC's ids), none when closed
    assert json.loads(read("SuspectBodies", [closed, {**opened, "bodies": [100007]}])) == [100007]
    assert json.loads(read("SuspectBodies", [opened])) == []  # the PLC gives no body ids
    assert read("SuspectBodies", [closed]) is None


async def _values_under(client: Client, root: Any) -> list[tuple[str, ua.DataValue]]:
    """Every variable's value below `root` (browsed recursively), read with both timestamps."""
    variables: list[Any] = []
    todo, seen = [root], {root.nodeid}
    while todo:
        node = todo.pop()
        refs = await node.get_references(
            refs=ua.ObjectIds.HierarchicalReferences, direction=ua.BrowseDirection.Forward
        )
        for ref in refs:
            if ref.NodeId in seen or ref.NodeId.NamespaceIndex == 0:
                continue  # the standard's own nodes (types, the server object)
            if ref.NodeClass in (ua.NodeClass.Object, ua.NodeClass.Variable):
                seen.add(ref.NodeId)
                child_node = client.get_node(ref.NodeId)
                if ref.NodeClass == ua.NodeClass.Variable:
                    variables.append(child_node)
                todo.append(child_node)
    params = ua.ReadParameters()
    params.TimestampsToReturn = ua.TimestampsToReturn.Both
    for node in variables:
        rv = ua.ReadValueId()
        rv.NodeId, rv.AttributeId = node.nodeid, ua.AttributeIds.Value
        params.NodesToRead.append(rv)
    results = await client.uaclient.read(params)
    return [(node.nodeid.to_string(), dv) for node, dv in zip(variables, results, strict=True)]


def test_every_value_rvis_writes_carries_a_server_timestamp(
    line: SimulatedLineRun, servers: Servers
) -> None:
    """rvis's variables, Identification, MachineryItemState and the alarm conditions' states:
    ServerTimestamp is the server's (wall) clock, SourceTimestamp the service's."""

    async def check() -> list[tuple[str, ua.DataValue]]:
        async with Client(servers.read_only) as client:
            m = await machine_node(client)
            values = await _values_under(client, m)
            names = [
                "ServiceState",
                "Windows",
                "CellTemperatureC",
                "Alarms/sensor/0:ActiveState/0:Id",
            ]
            for name in names:
                parts = name.split("/")
                node = await child(client, m, *parts)
                assert node.nodeid.to_string() in dict(values), name
            return values

    values = asyncio.run(check())
    now = time.time()
    written = [(n, dv) for n, dv in values if dv.StatusCode.is_good() or dv.SourceTimestamp]
    assert len(written) > 40
    missing = [n for n, dv in written if dv.ServerTimestamp is None]
    assert not missing, missing
    assert all(abs(dv.ServerTimestamp.timestamp() - now) < 600 for _, dv in written)


#: official NodeIds that exist only when the NodeSets are loaded (Machinery; DI)
MACHINERY_IDS = {
    1012: "MachineIdentificationType",
    1004: "MachineryItemIdentificationType",
    1002: "MachineryItemState_StateMachineType",
    1008: "MachineryOperationModeStateMachineType",
    5004: "OutOfService",
    5005: "NotAvailable",
    5006: "Executing",
    5007: "NotExecuting",
    5024: "None",
    5025: "Maintenance",
    5026: "Processing",
    5027: "Setup",
}
DI_IDS = {15054: "ISupportInfoType", 15035: "IVendorNameplateType", 1005: "FunctionalGroupType"}


def test_the_machine_found_by_the_official_types(line: SimulatedLineRun, servers: Servers) -> None:
    """A client that knows only OPC 40001-1 finds the cell under Machines by the official
    NodeIds (an AddIn whose type is MachineIdentificationType, i=1012; one whose type is
    MachineryItemState_StateMachineType, i=1002) and reads Identification and the state through
    them; the types and states are the NodeSets' nodes, their versions in Server/Namespaces."""

    async def check() -> dict[str, Any]:
        out: dict[str, Any] = {}
        async with Client(servers.read_only) as client:
            ns_m = await client.get_namespace_index(NS_MACHINERY)
            ns_di = await client.get_namespace_index(NS_DI)
            for ns, ids in ((ns_m, MACHINERY_IDS), (ns_di, DI_IDS)):
                for i, name in ids.items():
                    browse = await client.get_node(ua.NodeId(i, ns)).read_browse_name()
                    assert browse.Name == name, (i, browse)
            versions = {}
            namespaces = await client.nodes.server.get_child("0:Namespaces")
            for node in await namespaces.get_children():
                uri = await (await node.get_child("0:NamespaceUri")).read_value()
                versions[uri] = await (await node.get_child("0:NamespaceVersion")).read_value()
            out["versions"] = versions

            machines = client.get_node(ua.NodeId(1001, ns_m))
            found = []
            for machine in await machines.get_children(refs=ua.ObjectIds.Organizes):
                add_ins = await machine.get_references(
                    refs=ua.ObjectIds.HasAddIn, direction=ua.BrowseDirection.Forward
                )
                by_type = {r.TypeDefinition: client.get_node(r.NodeId) for r in add_ins}
                ident = by_type.get(ua.NodeId(1012, ns_m))
                state = by_type.get(ua.NodeId(1002, ns_m))
                mode = by_type.get(ua.NodeId(1008, ns_m))
                if ident is not None and state is not None and mode is not None:
                    found.append((machine, ident, state, mode))
            assert len(found) == 1, found
            machine, ident, state, mode = found[0]
            out["machine"] = (await machine.read_browse_name()).Name
            for prop in ("Manufacturer", "SerialNumber", "ProductInstanceUri", "Model"):
                out[prop] = await (await ident.get_child(f"{ns_di}:{prop}")).read_value()
            current = await state.get_child("0:CurrentState")
            # the text and its Id in one Read: the line runs on, and two reads may straddle a
            # change of state (Executing read, then NotExecuting's Id)
            text, state_id = await client.read_values([current, await current.get_child("0:Id")])
            out["state"] = text.Text
            out["state_node"] = (await client.get_node(state_id).read_browse_name()).Name
            out["state_id"] = state_id
            current = await mode.get_child("0:CurrentState")
            out["mode"] = (await current.read_value()).Text
            out["mode_id"] = await (await current.get_child("0:Id")).read_value()
            blocks = await machine.get_child(f"{ns_m}:MachineryBuildingBlocks")
            in_blocks = await blocks.get_references(
                refs=ua.ObjectIds.HasAddIn, direction=ua.BrowseDirection.Forward
            )
            add_ins = {ident.nodeid, state.nodeid, mode.nodeid}
            out["blocks"] = {r.NodeId for r in in_blocks} == add_ins
            out["ns_m"] = ns_m
        return out

    got = asyncio.run(check())
    assert got["versions"][NS_DI] == "1.04.0" and got["versions"][NS_MACHINERY] == "1.03.0"
    assert got["machine"] == MACHINE and got["blocks"]
    assert got["SerialNumber"] == "SN-0007" and got["Manufacturer"].Text == "rvis"
    assert got["ProductInstanceUri"] == "urn:plant-a:body-shop:cell-7"
    assert got["state"] == got["state_node"]  # CurrentState/Id is the official state object
    assert got["state_id"].NamespaceIndex == got["ns_m"]
    assert got["state_id"].Identifier in (5004, 5006, 5007)  # the line runs or is paused
    # MachineryOperationMode: the cell set up for its work (no maintenance in force)
    assert (got["mode"], got["mode_id"]) == ("Processing", ua.NodeId(5026, got["ns_m"]))


#: the `maintenance` need for axis 3's zero moved, as app.line.jumps makes it
AXIS3 = change_need(
    "J3", "J3 zero", "J3 zero moved 0.4935 deg, 3 measurements", "0.4935 deg", 9.91, 1.5
)


def test_a_cell_held_for_maintenance_reads_out_of_service_in_maintenance_mode(
    line: SimulatedLineRun, servers: Servers
) -> None:
    """Issue 41: the service holds the cell for maintenance (a change beyond a knock): a
    client reads MachineryItemState OutOfService, MachineryOperationMode Maintenance (both the
    NodeSet's state objects) and the Step naming the procedure; the engineer's reset (or the
    procedure's hand-over) puts the mode back to Processing."""

    def ask(cmd: str) -> None:
        reply = line.service.request(cmd).result(30)
        assert reply["ok"], reply

    async def check() -> None:
        async with Client(servers.read_only) as client:
            ns_m = await client.get_namespace_index(NS_MACHINERY)
            m = await machine_node(client)
            state = await m.get_child([f"{ns_m}:MachineryItemState", "0:CurrentState"])
            mode = await m.get_child([f"{ns_m}:MachineryOperationMode", "0:CurrentState"])
            step = await child(client, m, "Step")
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            await sub.subscribe_data_change([state, mode, step])

            async def until(node: Any, text: str) -> None:
                async with asyncio.timeout(20):
                    while (await node.read_value()).Text != text:
                        await handler.changes.get()

            await asyncio.to_thread(ask, "pause")  # no motion while the test holds the cell
            await until(state, "OutOfService")
            assert (await mode.read_value()).Text == "Processing"
            # what the service's step handling does for a change beyond a knock
            await asyncio.to_thread(line.service.maintenance_needed, AXIS3)
            await until(mode, "Maintenance")
            assert (await state.read_value()).Text == "OutOfService"
            mode_id = await (await mode.get_child("0:Id")).read_value()
            assert mode_id == ua.NodeId(5025, ns_m)  # the NodeSet's Maintenance
            state_id = await (await state.get_child("0:Id")).read_value()
            assert state_id == ua.NodeId(5004, ns_m)  # OutOfService
            assert await step.read_value() == "held for maintenance: run `rvis maintain axis 3`"
            need = line.service.status()["maintenance"]["needed"]  # what `rvis status` shows
            assert need["procedures"] == ["rvis maintain axis 3"] and need["text"] == AXIS3.text
            await asyncio.to_thread(ask, "reset")
            await until(mode, "Processing")
            await asyncio.to_thread(ask, "resume")
            async with asyncio.timeout(20):
                while (await state.read_value()).Text not in ("NotExecuting", "Executing"):
                    await handler.changes.get()

    try:
        asyncio.run(check())
    finally:  # the package's line left running normally, whatever failed
        if line.service.state.value == "fault":
            line.service.request("reset").result(30)
        if line.service.decision.paused:
            line.service.request("resume").result(30)
    assert line.service.state.value != "fault"
