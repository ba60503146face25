"""The bodies' results over OPC UA (docs/opcua.md "Body results"): one BodyResultEventType
event per body the service measured, in order, and the last body's summary as variables.

    Types/EventTypes/BaseEventType/BodyResultEventType (rvis)   FIELDS as its properties;
                                                               WorstDeviationMm an AnalogItemType
                                                               (EngineeringUnits mm, EURange)
    <machine>/LastBody (rvis)                                  FIELDS as read-only variables

The server process gets each `body` event of the service (app.line.body_cycle.BodyReport with
its params_version) from the feed, in order with the alarm changes, and `publish`es it: the
LastBody variables (SourceTimestamp: the service's clock at the body's event), then the event
from the machine and from the Server object (as the alarms' events: the machine is an event
notifier, app.line.opcua.alarms). A restarted server process is given the last body again
(`replay`): the variables only, no second event. Before the first body since the service
started the variables read BadNoValue, as does a field the body has not (no body id from the
PLC, no characteristic measured).
"""

from __future__ import annotations

import uuid
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from asyncua import Node, Server, ua
from asyncua.common.event_objects import BaseEvent

from app.line.opcua.space import AddressSpace, stamped
from app.line.opcua.variables import Var, data_value, eu_information, lookup

EVENT_TYPE = "BodyResultEventType"
LAST_BODY = "LastBody"
SEVERITY_OK = 100  # Part 5's range 1..1000: low
SEVERITY_NOK = 500  # medium: a body out of tolerance (or not measured), not a cell's fault
TYPE_TEXT = (
    "A body measured by the cell: its id, OK/NOK, how many characteristics are nonconforming,"
    " undecided and not measured, the characteristic furthest out of its tolerance and its"
    " deviation, the parameters version it was measured with"
)

#: a body's result: browse name, where the service's `body` event holds it, type, unit
FIELDS = (
    Var(
        "BodyId",
        ("body_id",),
        ua.VariantType.String,
        "the body's id as the line PLC gave it ([line] plc_body_id; no value: none given)",
        convert=str,
    ),
    Var(
        "Ok",
        ("ok",),
        ua.VariantType.Boolean,
        "no characteristic proven out of tolerance and every one measured (ISO 14253-1 with"
        " each value's U95)",
    ),
    Var(
        "NokCount",
        ("n_nok",),
        ua.VariantType.UInt32,
        "characteristics proven out of tolerance",
    ),
    Var(
        "UndecidedCount",
        ("n_undecided",),
        ua.VariantType.UInt32,
        "characteristics within their U95 of a limit: neither proven in nor out",
    ),
    Var(
        "NotMeasuredCount",
        ("n_not_measured",),
        ua.VariantType.UInt32,
        "characteristics without a value (no time left, the body withdrawn, the vision)",
    ),
    Var(
        "WorstCharacteristic",
        ("worst", "characteristic"),
        ua.VariantType.String,
        "the characteristic furthest out of (or nearest to leaving) its tolerance, as a share"
        " of it: <feature>.<X|Y|Z|D|W|L|N> (no value: none measured)",
    ),
    Var(
        "WorstDeviationMm",
        ("worst", "deviation_mm"),
        ua.VariantType.Double,
        "that characteristic's deviation from its nominal, measured - nominal (no value: none"
        " measured)",
        unit="mm",
        eu_range=(-10.0, 10.0),
    ),
    Var(
        "ParamsVersion",
        ("params_version",),
        ua.VariantType.UInt32,
        "the parameters version in force when the body was measured",
    ),
)


FIELD_COUNTS = ("n_nok", "n_not_measured", "n_undecided")


def severity(body: Mapping[str, Any]) -> int:
    """An OK body's event is low, a NOK one's medium."""
    return SEVERITY_OK if body.get("ok") else SEVERITY_NOK


def message(body: Mapping[str, Any]) -> str:
    """`body 100012 NOK: 2 characteristics out, 1 not measured, worst H03.X +0.41 mm`."""
    body_id = body.get("body_id")
    text = f"body {'(no id)' if body_id is None else body_id} {'OK' if body.get('ok') else 'NOK'}"
    nok, missing, undecided = (int(body.get(k) or 0) for k in FIELD_COUNTS)
    items = [f"{nok} characteristic{'s' if nok != 1 else ''} out"] if nok else []
    items += [f"{missing} not measured"] if missing else []
    items += [f"{undecided} undecided"] if undecided else []
    worst = body.get("worst") or {}
    if worst.get("characteristic") and worst.get("deviation_mm") is not None:
        items.append(f"worst {worst['characteristic']} {float(worst['deviation_mm']):+.2f} mm")
    if items:
        text += ": " + ", ".join(items)
    if body.get("withdrawn"):
        text += f" (withdrawn: {body['withdrawn']})"
    return text


def field_values(body: Mapping[str, Any], t: datetime) -> dict[str, ua.DataValue]:
    """Each field's value of `body` (BadNoValue where it has none), timestamped `t`."""
    return {var.name: data_value(var, lookup(body, var.path), t, None) for var in FIELDS}


class BodyResults:
    """The event type, the LastBody object and their publishing, on the AddressSpace built."""

    def __init__(self, server: Server, space: AddressSpace) -> None:
        assert space.machine is not None, "AddressSpace.build first"
        self.server, self.space, self.machine = server, space, space.machine
        self.type_id = ua.NodeId(EVENT_TYPE, space.ns)
        self._vars: dict[str, Node] = {}
        self._last_t: datetime | None = None
        self.name = ""

    async def setup(self, t: datetime) -> None:
        """The event type (GeneratesEvent from the cell's type) and LastBody, without a value
        (`t`: their SourceTimestamp)."""
        ns, s = self.space.ns, self.server
        self.name = (await self.machine.read_browse_name()).Name
        etype = await s.nodes.base_event_type.add_object_type(
            self.type_id, ua.QualifiedName(EVENT_TYPE, ns)
        )
        text = ua.Variant(ua.LocalizedText(TYPE_TEXT), ua.VariantType.LocalizedText)
        await etype.write_attribute(ua.AttributeIds.Description, ua.DataValue(text))
        for var in FIELDS:
            if var.unit:  # a variable with its EngineeringUnits, as the cell's variables
                node = await self.space.add_variable(etype, (EVENT_TYPE,), var)
                for prop in await node.get_properties():
                    await prop.set_modelling_rule(True)
            else:
                node = await etype.add_property(
                    ua.NodeId(f"{EVENT_TYPE}.{var.name}", ns),
                    ua.QualifiedName(var.name, ns),
                    ua.Variant(ua.get_default_value(var.vtype), var.vtype),
                    datatype=ua.NodeId(int(var.vtype.value)),
                )
            await node.set_modelling_rule(True)
        cell_type = await self.machine.read_type_definition()
        await s.get_node(cell_type).add_reference(self.type_id, ua.ObjectIds.GeneratesEvent)
        obj = await self.machine.add_object(
            ua.NodeId(f"{self.name}.{LAST_BODY}", ns), ua.QualifiedName(LAST_BODY, ns)
        )
        for var in FIELDS:
            self._vars[var.name] = await self.space.add_variable(obj, (self.name, LAST_BODY), var)
        await self._write(field_values({}, t))

    async def publish(self, body: Mapping[str, Any], t: datetime, replay: bool = False) -> int:
        """One body's result at `t` (the service's clock at its event): the LastBody
        variables, then the event (not on a `replay`; a replay older than the body shown:
        nothing), so that a client reading LastBody on the event reads that body or a later
        one; the number of events triggered."""
        if replay and self._last_t is not None and t < self._last_t:
            return 0
        values = field_values(body, t)
        await self._write(values)
        self._last_t = t
        return 0 if replay else await self._event(body, values, t)

    async def _event(
        self, body: Mapping[str, Any], values: Mapping[str, ua.DataValue], t: datetime
    ) -> int:
        event = BaseEvent(self.machine.nodeid, message(body), severity(body))
        event.EventType = self.type_id
        for var in FIELDS:
            dv = values[var.name]
            good = dv.Value is not None and dv.StatusCode.is_good()
            event.add_property(var.name, dv.Value.Value if good else None, var.vtype)
            if var.unit:
                lo, hi = var.eu_range or (0.0, 0.0)
                ext = ua.VariantType.ExtensionObject
                event.add_property(f"{var.name}/EngineeringUnits", eu_information(var.unit), ext)
                event.add_property(f"{var.name}/EURange", ua.Range(lo, hi), ext)
        event.EventId, event.Time = uuid.uuid4().bytes, t
        event.ReceiveTime = datetime.now(UTC)
        event.SourceName = self.name
        subscriptions = self.server.iserver.subscription_service
        for emitter in (self.machine.nodeid, ua.NodeId(ua.ObjectIds.Server)):
            event.emitting_node = emitter
            await subscriptions.trigger_event(event)
        return 1

    async def _write(self, values: Mapping[str, ua.DataValue]) -> None:
        for name, dv in values.items():
            await self.server.write_attribute_value(self._vars[name].nodeid, stamped(dv))
