"""The service's alarms as Alarms & Conditions events: an injected device fault arrives as an
event whose Time is the alarm's on the service's clock (the time it was raised, not when the
event was sent), with the priority's severity; acknowledging is refused unless
`[opcua] allow_ack`, and when allowed is the service's audited `ack`; shelving and `rvis ctl
reset` (clearing) follow, and ConditionRefresh replays what is active. Alarm changes travel
as events, in order: an alarm raised and cleared between two status replies is two OPC UA
events (issue 39 item 2)."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

import pytest
from asyncua import Client, Node, ua

from app.line.opcua.space import clock_utc
from app.line.states import ALARM_CODES
from app.sim.line_run import SimulatedLineRun
from fakes.line_faults import Fault
from tests.opcua.conftest import Catcher, Servers, child, machine_node, rvis

ACTIVE, ACKED = "ActiveState/Id", "AckedState/Id"


class AlarmWatch:
    """The id of the alarm of `code` the service's event bus carries next."""

    def __init__(self, run: SimulatedLineRun, code: str) -> None:
        self.run, self.code = run, code
        self.alarm_id: int | None = None
        self._q = run.service.bus.subscribe()
        self.seen = threading.Event()
        threading.Thread(target=self._wait, daemon=True).start()

    def _wait(self) -> None:
        while True:
            event = self._q.get()
            if event["event"] == "alarm" and event["code"] == self.code:
                self.alarm_id = int(event["id"])
                self.seen.set()
                self.run.service.bus.unsubscribe(self._q)
                return


def _alarm(run: SimulatedLineRun, alarm_id: int) -> dict[str, Any]:
    """The service's alarm `alarm_id`, as stored."""
    found = [a for a in run.service.store.alarms() if a["id"] == alarm_id]
    assert len(found) == 1, f"no alarm {alarm_id}"
    return found[0]


def _field(event: Any, name: str) -> Any:
    return getattr(event, name, None)


def _is(code: str, **fields: Any) -> Any:
    def pred(event: Any) -> bool:
        if _field(event, "ConditionName") != code:
            return False
        return all(_field(event, k.replace("__", "/")) == v for k, v in fields.items())

    return pred


async def acknowledge(client: Client, condition: Node, event_id: bytes, comment: str) -> None:
    await condition.call_method(
        ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
        ua.Variant(event_id, ua.VariantType.ByteString),
        ua.Variant(ua.LocalizedText(comment), ua.VariantType.LocalizedText),
    )


def test_a_device_fault_as_alarm_events_from_raise_to_clear(
    line: SimulatedLineRun, servers: Servers
) -> None:
    url_ro, url_ack = servers.read_only, servers.acking

    async def scenario() -> None:
        async with Client(url_ro) as ro, Client(url_ack) as op:
            handler, handler_op = Catcher(), Catcher()
            for client, h in ((ro, handler), (op, handler_op)):
                sub = await client.create_subscription(20, h)
                await sub.subscribe_events(client.nodes.server, ua.ObjectIds.AlarmConditionType)
            watch = AlarmWatch(line, "device_fault")
            line.line.inject(Fault.CONTROLLER_ALARM)  # the next motion stops on it
            _, raised = await handler.event(_is("device_fault", ActiveState__Id=True), 10)
            assert watch.seen.wait(5) and watch.alarm_id is not None
            alarm = _alarm(line, watch.alarm_id)
            assert alarm["code"] == "device_fault"
            assert raised.Time == clock_utc(alarm["t_raised"])  # the service's time of it
            assert raised.Severity == 900 and raised.Retain  # urgent
            assert _field(raised, ACKED) is False and "DeviceFault" in raised.Message.Text

            # read-only server: the Acknowledge method is refused, nothing audited
            m_ro = await machine_node(ro)
            condition = await child(ro, m_ro, "Alarms", "device_fault")
            assert raised.NodeId == condition.nodeid  # the event's ConditionId
            n_actions = len(line.service.store.actions())
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await acknowledge(ro, condition, raised.EventId, "seen")
            assert len(line.service.store.actions()) == n_actions

            # allowed (another server: its own event ids): the service's ack, audited
            _, raised_op = await handler_op.event(_is("device_fault", ActiveState__Id=True))
            condition_op = op.get_node(raised_op.NodeId)
            await acknowledge(op, condition_op, raised_op.EventId, "seen from SCADA")
            _, acked = await handler.event(_is("device_fault", AckedState__Id=True))
            assert _field(acked, ACTIVE) is True and acked.Retain
            assert acked.Comment.Text == "seen from SCADA" and acked.ClientUserId == "anonymous"
            comment = await (await condition.get_child("0:Comment")).read_value()
            assert comment.Text == "seen from SCADA"  # the condition's variable too
            last = line.service.store.actions()[-1]
            assert last["cmd"] == "ack" and last["ok"]
            assert last["args"]["alarm"] == alarm["id"] and last["args"]["via"] == "opcua"
            assert last["args"]["comment"] == "seen from SCADA"
            assert _alarm(line, alarm["id"])["state"] == "acked"
            _, acked_op = await handler_op.event(_is("device_fault", AckedState__Id=True))
            with pytest.raises(ua.uaerrors.BadConditionBranchAlreadyAcked):
                await acknowledge(op, condition_op, acked_op.EventId, "again")

            # shelved by an operator at the terminal, then the fault reset
            await asyncio.to_thread(rvis, line, "ctl", "shelve", str(alarm["id"]), "robot checked")
            await handler.event(_is("device_fault", SuppressedOrShelved=True))
            await asyncio.to_thread(rvis, line, "ctl", "reset")
            _, cleared = await handler.event(_is("device_fault", ActiveState__Id=False))
            assert not cleared.Retain and cleared.NodeId == condition.nodeid
            assert (await (await child(ro, m_ro, "ActiveAlarms")).read_value()) == len(
                line.service.status()["alarms"]
            )

    asyncio.run(scenario())
    assert line.service.state.value != "fault"


def test_condition_refresh_replays_the_active_alarms(
    line: SimulatedLineRun, servers: Servers
) -> None:
    url = servers.read_only
    watch = AlarmWatch(line, "device_fault")
    line.line.inject(Fault.ROBOT_DISCONNECT)
    assert watch.seen.wait(20)

    async def scenario() -> Any:
        async with Client(url) as client:  # connects after the alarm was raised
            handler = Catcher()
            sub = await client.create_subscription(20, handler)
            await sub.subscribe_events(client.nodes.server, ua.ObjectIds.AlarmConditionType)
            await client.nodes.server.call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(sub.subscription_id, ua.VariantType.UInt32),
            )
            _, event = await handler.event(_is("device_fault", ActiveState__Id=True))
            await asyncio.to_thread(rvis, line, "ctl", "reset")
            await handler.event(_is("device_fault", ActiveState__Id=False))
            return event

    event = asyncio.run(scenario())
    assert event.Severity == 900 and "DeviceConnectionError" in event.Message.Text


def test_an_alarm_raised_and_cleared_between_two_publishes_is_two_events(
    line: SimulatedLineRun, servers: Servers
) -> None:
    """An alarm blip (raised and cleared well within 50 ms, inside one transaction: no status
    reply can be taken between them, and faster than the subscription's publishing interval)
    reaches a subscriber of the Server object as two events of its condition, active then
    inactive, each with the time of its change on the service's clock."""
    svc = line.service
    code = "params_rebuilt"  # raised only at a start: the running line leaves it alone
    assert code not in {a["code"] for a in svc.status()["alarms"]}

    async def scenario() -> list[Any]:
        async with Client(servers.read_only) as client:
            handler = Catcher()
            sub = await client.create_subscription(500, handler)
            await sub.subscribe_events(client.nodes.server, ua.ObjectIds.AlarmConditionType)
            with svc.store.batch():
                alarm_id = svc.alarm(code, "a blip", "medium")
                svc.clear_alarms(code)
            raised = (await handler.event(_is(code), 10))[1]
            cleared = (await handler.event(_is(code), 10))[1]
            assert (_field(raised, ACTIVE), _field(cleared, ACTIVE)) == (True, False)
            row = _alarm(line, alarm_id)
            assert raised.Time == clock_utc(row["t_raised"]) and raised.Severity == 500
            assert cleared.Time == clock_utc(row["t_cleared"]) and not cleared.Retain
            assert raised.NodeId == cleared.NodeId and raised.EventId != cleared.EventId
            return [raised, cleared]

    asyncio.run(scenario())


def test_every_alarm_condition_is_there_from_the_start(
    line: SimulatedLineRun, servers: Servers
) -> None:
    """Alarms/ holds one AlarmConditionType condition per code of ALARM_CODES (raised or not),
    each subscribable: the codes not active read ActiveState Inactive, Retain false; every one
    has a Severity and a Message (never raised: the lowest severity, not Null)."""
    active = {a["code"] for a in line.service.status()["alarms"]}

    async def check() -> dict[str, tuple[bool, bool, Any]]:
        async with Client(servers.read_only) as client:
            folder = await child(client, await machine_node(client), "Alarms")
            out = {}
            items = []
            for node in await folder.get_children():
                name = (await node.read_browse_name()).Name
                typedef = await node.read_type_definition()
                state = await node.get_child(["0:ActiveState", "0:Id"])
                retain = await node.get_child("0:Retain")
                out[name] = (await state.read_value(), await retain.read_value(), typedef)
                items.append(state)
                severity = await (await node.get_child("0:Severity")).read_value()
                assert isinstance(severity, int) and 1 <= severity <= 1000, (name, severity)
                message = await (await node.get_child("0:Message")).read_value()
                assert isinstance(message, ua.LocalizedText), (name, message)
            sub = await client.create_subscription(50, Catcher())
            handles = await sub.subscribe_data_change(items)
            assert all(isinstance(h, int) for h in handles)  # each monitored item created
            return out

    conditions = asyncio.run(check())
    assert set(conditions) == set(ALARM_CODES)
    alarm_type = ua.NodeId(ua.ObjectIds.AlarmConditionType)
    assert all(t == alarm_type for _, _, t in conditions.values())
    for code, (state, retain, _) in conditions.items():
        if code not in active:
            assert state is False and retain is False, code


def test_a_shelved_alarm_raised_again_stays_shelved_for_its_time(
    line: SimulatedLineRun, servers: Servers
) -> None:
    """ISA-18.2 shelves the alarm, not one occurrence of it: shelved for 5 minutes, cleared,
    and raised again 4 s later (the service's clock), it is raised shelved until the same time
    (OPC UA: TimedShelved, SuppressedOrShelved) and comes back only when that time is up
    (before: the new occurrence came back Unshelved)."""
    svc, clock = line.service, line.clock
    code = "params_rebuilt"  # raised only at a start: the running line leaves it alone
    assert code not in {a["code"] for a in svc.status()["alarms"]}
    bus = svc.bus.subscribe()
    try:

        async def scenario() -> tuple[int, Any]:
            async with Client(servers.read_only) as client:
                handler = Catcher()
                sub = await client.create_subscription(20, handler)
                await sub.subscribe_events(client.nodes.server, ua.ObjectIds.AlarmConditionType)
                first = svc.alarm(code, "parameters rebuilt", "medium")
                args = {"alarm": first, "reason": "sensor cleaned", "minutes": 5}
                reply = await asyncio.to_thread(lambda: svc.request("shelve", args).result(30))
                assert reply["ok"], reply
                await handler.event(_is(code, SuppressedOrShelved=True))
                svc.clear_alarms(code)
                await handler.event(_is(code, ActiveState__Id=False))
                later = threading.Event()
                clock.call_at(clock.monotonic() + 4.0, later.set)
                assert await asyncio.to_thread(later.wait, 10)
                second = svc.alarm(code, "parameters rebuilt again", "medium")
                _, raised = await handler.event(_is(code, ActiveState__Id=True))
                return second, raised

        second, raised = asyncio.run(scenario())
        row = _alarm(line, second)
        shelved = [a for a in svc.store.alarms() if a["code"] == code and a["id"] < second]
        assert row["state"] == "shelved", row
        assert row["shelved_until"] == shelved[-1]["shelved_until"]
        assert row["shelve_reason"] == "sensor cleaned"
        assert raised.SuppressedOrShelved is True
        assert _field(raised, "ShelvingState/CurrentState").Text == "TimedShelved"
        # it comes back when its time is up, not before
        while True:
            event = bus.get(timeout=30)
            if event["event"] == "alarm_unshelved" and event.get("id") == second:
                break
        assert svc.clock.time() >= row["shelved_until"]
    finally:
        svc.bus.unsubscribe(bus)
        svc.clear_alarms(code)
