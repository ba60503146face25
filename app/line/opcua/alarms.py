"""The service's alarms as OPC UA Alarms & Conditions (docs/opcua.md), so that a SCADA alarm
list shows them.

One condition per alarm code (`Alarms/<code>` under the machine, an AlarmConditionType
instance referenced by HasCondition), every code of app.line.states.ALARM_CODES from the start
(inactive, Severity IDLE_SEVERITY, so that a client can browse and subscribe to all of them):
the service keeps at most one active alarm per code, and each of its alarm rows is one
occurrence of that condition. `apply(change)` takes each alarm change of the service's events,
in order; `sync(alarms)` compares a status reply's alarms with the occurrences published (at
the start, and to repair alarm events lost on the way). Either triggers an event for every
change, from the machine and from the Server object, with the condition's variables written
to match:

    raised              ActiveState Active, AckedState Unacknowledged, Retain true
    acked               AckedState Acknowledged, Comment and ClientUserId the acknowledge's
    shelved / unshelved ShelvingState TimedShelved / Unshelved (SuppressedOrShelved)
    cleared             ActiveState Inactive, Retain false (the service needs no ack after)

Severity follows the ISA-18.2 priority (urgent 900, high 700, medium 500, low 300). Retained
conditions are replayed by ConditionRefresh (on subscriptions to the Server object).
Acknowledge (the AcknowledgeableConditionType method, on the type or the condition) is refused
unless `[opcua] allow_ack`; allowed, it goes through the service's audited `ack` command.
"""

from __future__ import annotations

import contextlib
import logging
import uuid
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from asyncua import Node, Server, ua
from asyncua.common.event_objects import AlarmCondition

from app.line.opcua.security import caller
from app.line.opcua.space import now_utc
from app.line.states import ALARM_CODES

log = logging.getLogger("rvis.line.opcua")

SEVERITY = {"urgent": 900, "high": 700, "medium": 500, "low": 300}
IDLE_SEVERITY = 1  # a condition never raised since the start (Part 5's range is 1..1000)
IDLE_MESSAGE = "not raised since the OPC UA server started"
SHELVING_IDS = {
    "Unshelved": ua.ObjectIds.ShelvedStateMachineType_Unshelved,
    "TimedShelved": ua.ObjectIds.ShelvedStateMachineType_TimedShelved,
}

#: acknowledge(alarm id, who, comment) -> None when done, else the service's reason
AckHandler = Callable[[int, str, str], Awaitable[str | None]]


@dataclass
class Occurrence:
    """The alarm row published on a condition."""

    alarm_id: int
    state: str  # raised | acked | shelved
    acked: bool = False
    event_ids: set[bytes] = field(default_factory=set)
    comment: str = ""  # the acknowledge's
    user: str = ""  # who acknowledged

    def move(self, state: str) -> None:
        self.acked = state == "acked" or (state == "shelved" and self.acked)
        self.state = state


def condition_fields(
    alarm: Mapping[str, Any], occ: Occurrence, active: bool
) -> dict[str, tuple[Any, ua.VariantType]]:
    """The condition's fields (event field path -> value, type) for this occurrence."""
    shelving = "TimedShelved" if occ.state == "shelved" else "Unshelved"
    klass = "Process" if ALARM_CODES.get(str(alarm["code"])) == "process" else "System"
    class_id = getattr(ua.ObjectIds, f"{klass}ConditionClassType")
    text = ua.VariantType.LocalizedText
    return {
        "ConditionName": (str(alarm["code"]), ua.VariantType.String),
        "ConditionClassId": (ua.NodeId(class_id), ua.VariantType.NodeId),
        "ConditionClassName": (ua.LocalizedText(klass), text),
        "Severity": (SEVERITY.get(str(alarm["priority"]), 500), ua.VariantType.UInt16),
        "Message": (ua.LocalizedText(str(alarm["message"])), text),
        "Retain": (active, ua.VariantType.Boolean),
        "EnabledState": (ua.LocalizedText("Enabled"), text),
        "EnabledState/Id": (True, ua.VariantType.Boolean),
        "ActiveState": (ua.LocalizedText("Active" if active else "Inactive"), text),
        "ActiveState/Id": (active, ua.VariantType.Boolean),
        "AckedState": (ua.LocalizedText("Acknowledged" if occ.acked else "Unacknowledged"), text),
        "AckedState/Id": (occ.acked, ua.VariantType.Boolean),
        "ShelvingState/CurrentState": (ua.LocalizedText(shelving), text),
        "ShelvingState/CurrentState/Id": (ua.NodeId(SHELVING_IDS[shelving]), ua.VariantType.NodeId),
        "SuppressedOrShelved": (shelving != "Unshelved", ua.VariantType.Boolean),
        "Comment": (ua.LocalizedText(occ.comment), text),
        "ClientUserId": (occ.user, ua.VariantType.String),
    }


class Conditions:
    """The alarm conditions of one machine node."""

    def __init__(
        self, server: Server, ns: int, machine: Node, ack: AckHandler | None = None
    ) -> None:
        self.server, self.ns, self.machine, self.ack = server, ns, machine, ack
        self._folder: Node | None = None
        self._nodes: dict[str, Node] = {}  # code -> condition node
        self._codes: dict[ua.NodeId, str] = {}  # condition node id -> code
        self._vars: dict[tuple[str, str], Node | None] = {}  # (code, field path) -> variable
        self._now: dict[str, tuple[Occurrence, dict[str, Any]]] = {}  # code -> occurrence
        self.name = ""

    async def setup(self) -> None:
        """The Alarms folder, the event notifiers and the Acknowledge method's callback."""
        self.name = (await self.machine.read_browse_name()).Name
        self._folder = await self.machine.add_folder(
            ua.NodeId(f"{self.name}.Alarms", self.ns), ua.QualifiedName("Alarms", self.ns)
        )
        await self.machine.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
        await self.server.nodes.server.add_reference(self.machine.nodeid, ua.ObjectIds.HasNotifier)
        method = self.server.get_node(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
        self.server.link_method(method, self._acknowledge)
        for code in ALARM_CODES:
            node = await self._condition(code)
            idle = {"code": code, "priority": "", "message": IDLE_MESSAGE}
            fields = condition_fields(idle, Occurrence(0, "cleared"), False)
            fields["Severity"] = (IDLE_SEVERITY, ua.VariantType.UInt16)
            await self._write(code, node, fields)

    async def _condition(self, code: str) -> Node:
        node = self._nodes.get(code)
        if node is None:
            assert self._folder is not None, "setup() first"
            node = await self._folder.add_object(
                ua.NodeId(f"{self.name}.Alarms.{code}", self.ns),
                ua.QualifiedName(code, self.ns),
                objecttype=ua.ObjectIds.AlarmConditionType,
            )
            await self.machine.add_reference(node.nodeid, ua.ObjectIds.HasCondition)
            with contextlib.suppress(ua.UaError):
                own = await node.get_child("0:Acknowledge")
                self.server.link_method(own, self._acknowledge)
            self._nodes[code], self._codes[node.nodeid] = node, code
        return node

    async def sync(self, alarms: list[Mapping[str, Any]], t: datetime) -> int:
        """Publish what differs from `alarms` (a status reply's, one per code); the number of
        events triggered."""
        events = 0
        seen = {str(a["code"]): a for a in alarms}
        for code, (occ, _) in list(self._now.items()):
            if code not in seen or int(seen[code]["id"]) != occ.alarm_id:
                events += await self._clear(code, occ.alarm_id, t)  # cleared (or replaced)
        for alarm in seen.values():
            events += await self._set(alarm, str(alarm["state"]), t)
        return events

    async def apply(self, change: Mapping[str, Any], t: datetime) -> int:
        """One alarm change of the service's events (`change`: id, code, `state` after it,
        priority, message, comment and user of an acknowledge, `change` the event), at `t`;
        the number of events triggered (0: nothing new for a client, e.g. a raise of the
        occurrence published already, or a change of an occurrence cleared already)."""
        code, alarm_id, state = str(change["code"]), int(change["id"]), str(change["state"])
        published = self._now.get(code)
        if state == "cleared":
            return await self._clear(code, alarm_id, t)
        if published is None and change.get("change") not in (None, "alarm"):
            return 0  # a change of an occurrence this server has not seen raised: the status
        events = 0
        if published is not None and published[0].alarm_id != alarm_id:
            events += await self._clear(code, published[0].alarm_id, t)  # replaced
        elif published is not None and change.get("change") == "alarm":
            return 0  # raised again while active: the service keeps the one alarm
        return events + await self._set(change, state, t)

    async def _set(self, alarm: Mapping[str, Any], state: str, t: datetime) -> int:
        """The occurrence `alarm` of its code in `state` (published when new or changed)."""
        code, alarm_id = str(alarm["code"]), int(alarm["id"])
        published = self._now.get(code)
        if published is not None and published[0].alarm_id == alarm_id:
            occ, last = published
            if occ.state == state and "comment" not in alarm:
                return 0
        else:
            occ, last = Occurrence(alarm_id, state), {}
        occ.move(state)
        if "comment" in alarm:  # an acknowledge's: Part 9's Comment and ClientUserId
            occ.comment, occ.user = str(alarm["comment"]), str(alarm.get("user", ""))
        merged = {**last, **{k: v for k, v in alarm.items() if v is not None}}
        self._now[code] = (occ, merged)
        await self._event(code, merged, occ, True, t)
        return 1

    async def _clear(self, code: str, alarm_id: int, t: datetime) -> int:
        """The occurrence `alarm_id` of `code` cleared (nothing when it is not published)."""
        published = self._now.get(code)
        if published is None or published[0].alarm_id != alarm_id:
            return 0
        occ, last = published
        await self._event(code, last, occ, False, t)
        del self._now[code]
        return 1

    async def _event(
        self, code: str, alarm: Mapping[str, Any], occ: Occurrence, active: bool, t: datetime
    ) -> None:
        node = await self._condition(code)
        fields = condition_fields(alarm, occ, active)
        event = AlarmCondition()
        event.add_property("NodeId", node.nodeid, ua.VariantType.NodeId)  # the ConditionId
        for path, (value, vtype) in fields.items():
            event.add_property(path, value, vtype)
        event_id = uuid.uuid4().bytes
        occ.event_ids.add(event_id)
        event.EventId, event.Time = event_id, t
        event.ReceiveTime = datetime.now(UTC)
        event.SourceNode, event.SourceName = self.machine.nodeid, self.name
        subscriptions = self.server.iserver.subscription_service
        for emitter in (self.machine.nodeid, ua.NodeId(ua.ObjectIds.Server)):
            event.emitting_node = emitter  # the Server object last: ConditionRefresh's source
            await subscriptions.trigger_event(event)
        await self._write(code, node, {**fields, "EventId": (event_id, ua.VariantType.ByteString)})

    async def _write(
        self, code: str, node: Node, fields: Mapping[str, tuple[Any, ua.VariantType]]
    ) -> None:
        """The condition node's variables in step with its last event."""
        for path, (value, vtype) in fields.items():
            key = (code, path)
            if key not in self._vars:
                try:
                    self._vars[key] = await node.get_child([f"0:{p}" for p in path.split("/")])
                except ua.UaError:
                    self._vars[key] = None  # an optional field this instance does not have
            var = self._vars[key]
            if var is not None:
                await self.server.write_attribute_value(
                    var.nodeid, ua.DataValue(ua.Variant(value, vtype), ServerTimestamp=now_utc())
                )

    async def _acknowledge(
        self, condition: ua.NodeId, event_id: ua.Variant, comment: ua.Variant | None = None
    ) -> ua.StatusCode | list[ua.Variant]:
        """The Acknowledge method (Part 9): refused unless allowed, else the service's `ack`
        of the alarm the event belongs to, audited with who asked and the comment."""
        code = self._codes.get(condition)
        published = self._now.get(code) if code is not None else None
        if published is None or event_id.Value not in published[0].event_ids:
            return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
        occ = published[0]
        who = caller()
        if self.ack is None:
            log.warning(
                "OPC UA acknowledge of alarm %d by %s refused: [opcua] allow_ack is false",
                occ.alarm_id,
                who,
            )
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        if occ.acked:
            return ua.StatusCode(ua.StatusCodes.BadConditionBranchAlreadyAcked)
        text = comment.Value.Text if comment is not None and comment.Value is not None else ""
        error = await self.ack(occ.alarm_id, who, text or "")
        if error is not None:
            log.warning("OPC UA acknowledge of alarm %d by %s failed: %s", occ.alarm_id, who, error)
            return ua.StatusCode(ua.StatusCodes.BadInvalidState)
        return []
