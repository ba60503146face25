"""The address space of the cell (docs/opcua.md): a machine of OPC 40001-1 (Machinery) with
rvis's own variables, and how a status reply of the service becomes their values.

    Objects/Machines (Machinery, i=1001)            from the official Machinery NodeSet
        <machine_name> (rvis)                        RvisCellType, an event notifier
            Identification (DI)                      MachineIdentificationType (HasAddIn)
            MachineryBuildingBlocks (Machinery)      HasAddIn Identification, MachineryItemState,
                                                     MachineryOperationMode
            MachineryItemState (Machinery)           MachineryItemState_StateMachineType (HasAddIn)
            MachineryOperationMode (Machinery)       MachineryOperationModeStateMachineType
                                                     (HasAddIn)
            ServiceState, Step, CalibrationVersion, ... (rvis)   app.line.opcua.variables
            Spheres/<id>/ResidualMm, PosteriorRmsMm (rvis)
            LastBody/BodyId, Ok, ... (rvis)          the last body's result; each body's
                                                     BodyResultEventType (app.line.opcua.results)
            Alarms/<code> (rvis)                     AlarmConditionType (app.line.opcua.alarms)

The OPC Foundation's DI and Machinery NodeSets (NODESETS, shipped as they are in `nodesets/`)
are imported first, so the types, the Machines folder and the states the MachineryItemState's
and MachineryOperationMode's CurrentState/Id point to are the official nodes. asyncua's
`instantiate` links an instance with HasComponent: the AddIns are re-linked with HasAddIn.
Every variable is read-only; a value the service does not have (no fit RMS for initial
parameters, no temperature sensor, a sphere not measured yet) reads as BadNoValue, a value the
status reply left out (the state storage failing) keeps its last value as
UncertainLastUsableValue (app.line.opcua.variables).
"""

from __future__ import annotations

import contextlib
import dataclasses
import socket
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asyncua import Node, Server, ua
from asyncua.common.instantiate_util import instantiate

from app.line.maintenance_state import MODE_NONE, operation_mode
from app.line.opcua.variables import (
    VARIABLES,
    Var,
    data_value,
    eu_information,
    lookup,
    sphere_vars,
)

if TYPE_CHECKING:
    from app.config.line import OpcUaSettings  # (the server process does not import it)


NS_RVIS = "urn:rvis:opcua"  # the same in every cell: clients find the variables by name
NS_DI = "http://opcfoundation.org/UA/DI/"
NS_MACHINERY = "http://opcfoundation.org/UA/Machinery/"

#: the official NodeSets rvis loads, in import order (DI first: Machinery requires it); the
#: files are the OPC Foundation's, as published (docs/opcua.md names their versions)
NODESET_DIR = Path(__file__).resolve().parent / "nodesets"
NODESETS = (
    (NS_DI, "Opc.Ua.Di.NodeSet2.xml"),
    (NS_MACHINERY, "Opc.Ua.Machinery.NodeSet2.xml"),
)
#: OPC 40001-1 node ids in the Machinery namespace (Opc.Ua.Machinery.NodeIds.csv)
MACHINES_ID = 1001
MACHINE_IDENTIFICATION_TYPE = 1012
ITEM_STATE_TYPE = 1002  # MachineryItemState_StateMachineType
ITEM_STATE_IDS = {
    "OutOfService": 5004,
    "NotAvailable": 5005,
    "Executing": 5006,
    "NotExecuting": 5007,
}
OPERATION_MODE_TYPE = 1008  # MachineryOperationModeStateMachineType
OPERATION_MODE_IDS = {
    "None": 5024,
    "Maintenance": 5025,
    "Processing": 5026,
    "Setup": 5027,
}
#: the service's state -> MachineryItemState (40001-1: NotExecuting = ready, waiting for work);
#: held for maintenance (the `maintenance` alarm, a FAULT) it is OutOfService and the
#: MachineryOperationMode Maintenance (app.line.maintenance_state.operation_mode)
ITEM_STATE_OF = {
    "starting": "NotAvailable",
    "idle": "NotExecuting",
    "measuring": "Executing",
    "paused": "OutOfService",
    "fault": "OutOfService",
    "stopped": "NotAvailable",
}


def identity(settings: OpcUaSettings) -> dict[str, str]:
    """SerialNumber and ProductInstanceUri as published ("" settings derived)."""
    serial = settings.serial_number or socket.gethostname()
    uri = settings.product_instance_uri or (
        f"urn:{settings.manufacturer}:{serial}:{settings.machine_name}".replace(" ", "-")
    )
    return {"serial_number": serial, "product_instance_uri": uri}


class AddressSpace:
    """Builds the nodes (`build`) and writes a status reply into them (`apply`)."""

    def __init__(self, server: Server, settings: OpcUaSettings) -> None:
        self.server, self.settings = server, settings
        self.machine: Node | None = None
        self._vars: dict[str, tuple[Var, Node]] = {}  # node path -> variable and its node
        self._last: dict[str, ua.DataValue] = {}
        #: per state machine ("item": MachineryItemState, "mode": MachineryOperationMode): its
        #: CurrentState, its Id, the ids of the type's states, and the state published
        self._machines: dict[str, tuple[Node, Node, dict[str, int]]] = {}
        self._now: dict[str, str] = {}
        self.ns = self.ns_di = self.ns_machinery = 0

    async def build(self, spheres: list[str], software_revision: str, t: datetime) -> Node:
        """The nodes; `t`: Identification's SourceTimestamp (the service's clock at the
        start)."""
        s = self.server
        await load_nodesets(s)
        self.ns_di = await s.get_namespace_index(NS_DI)
        self.ns_machinery = await s.get_namespace_index(NS_MACHINERY)
        self.ns = await s.register_namespace(NS_RVIS)
        machines = s.get_node(ua.NodeId(MACHINES_ID, self.ns_machinery))
        cell_type = await s.nodes.base_object_type.add_object_type(
            ua.NodeId("RvisCellType", self.ns), ua.QualifiedName("RvisCellType", self.ns)
        )
        text = ua.Variant(ua.LocalizedText(CELL_TYPE_TEXT), ua.VariantType.LocalizedText)
        await cell_type.write_attribute(ua.AttributeIds.Description, ua.DataValue(text))
        name = self.settings.machine_name
        self.machine = machine = await self._add(
            machines,
            self._id(name),
            ua.QualifiedName(name, self.ns),
            cell_type.nodeid,
            ua.ObjectIds.Organizes,
        )
        ident = await self._identification(machine, software_revision, t)
        state = await self._state_machine(
            machine, "item", ITEM_STATE_TYPE, "MachineryItemState", ITEM_STATE_IDS, "NotAvailable"
        )
        mode = await self._state_machine(
            machine,
            "mode",
            OPERATION_MODE_TYPE,
            "MachineryOperationMode",
            OPERATION_MODE_IDS,
            MODE_NONE,
        )
        blocks = await self._add(
            machine,
            self._id(name, "MachineryBuildingBlocks"),
            ua.QualifiedName("MachineryBuildingBlocks", self.ns_machinery),
            ua.ObjectIds.FolderType,
        )
        for node in (ident, state, mode):
            await blocks.add_reference(node.nodeid, ua.ObjectIds.HasAddIn)
        for var in VARIABLES:
            await self._variable(machine, (name,), var)
        folder = await self._add(
            machine,
            self._id(name, "Spheres"),
            ua.QualifiedName("Spheres", self.ns),
            ua.ObjectIds.FolderType,
        )
        for sphere in spheres:
            label = sphere
            obj = await self._add(
                folder,
                self._id(name, "Spheres", label),
                ua.QualifiedName(label, self.ns),
                ua.ObjectIds.BaseObjectType,
            )
            for var in sphere_vars(sphere):
                await self._variable(obj, (name, "Spheres", label), var)
        return machine

    def _id(self, *path: str) -> ua.NodeId:
        return ua.NodeId(".".join(path), self.ns)

    async def _add_in(self, machine: Node, type_id: int, browse: ua.QualifiedName) -> Node:
        """An instance of the Machinery type `type_id` (its mandatory nodes), an AddIn of the
        machine: asyncua's `instantiate` links it with HasComponent, 40001-1 asks HasAddIn."""
        name = self.settings.machine_name
        node_type = self.server.get_node(ua.NodeId(type_id, self.ns_machinery))
        nodes = await instantiate(
            machine,
            node_type,
            nodeid=self._id(name, browse.Name),
            bname=browse,
            instantiate_optional=False,
        )
        node = nodes[0]
        await machine.delete_reference(node.nodeid, ua.ObjectIds.HasComponent)
        await machine.add_reference(node.nodeid, ua.ObjectIds.HasAddIn)
        return node

    async def _identification(self, machine: Node, software_revision: str, t: datetime) -> Node:
        """Identification: a MachineIdentificationType (its mandatory Manufacturer,
        SerialNumber, ProductInstanceUri), with the optional Model and SoftwareRevision."""
        s, name = self.settings, self.settings.machine_name
        ident = await self._add_in(
            machine,
            MACHINE_IDENTIFICATION_TYPE,
            ua.QualifiedName("Identification", self.ns_di),
        )
        derived = identity(s)
        values: list[tuple[str, Any, ua.VariantType]] = [
            ("Manufacturer", ua.LocalizedText(s.manufacturer), ua.VariantType.LocalizedText),
            ("Model", ua.LocalizedText(s.model), ua.VariantType.LocalizedText),
            ("SerialNumber", derived["serial_number"], ua.VariantType.String),
            ("SoftwareRevision", software_revision, ua.VariantType.String),
            ("ProductInstanceUri", derived["product_instance_uri"], ua.VariantType.String),
        ]
        for prop, value, vtype in values:
            qname = ua.QualifiedName(prop, self.ns_di)
            try:
                node = await ident.get_child(qname)
            except ua.UaError:  # an optional property the type's instance has not
                node = await ident.add_property(
                    self._id(name, "Identification", prop),
                    qname,
                    ua.Variant(value, vtype),
                    datatype=ua.NodeId(ua.ObjectIds.LocalizedText)
                    if vtype == ua.VariantType.LocalizedText
                    else None,
                )
            await self.server.write_attribute_value(
                node.nodeid, stamped(ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=t))
            )
        return ident

    async def _state_machine(
        self,
        machine: Node,
        key: str,
        type_id: int,
        browse: str,
        ids: dict[str, int],
        initial: str,
    ) -> Node:
        """A state machine of Machinery's type `type_id` (MachineryItemState_StateMachineType,
        MachineryOperationModeStateMachineType), an AddIn; CurrentState and its Id point to the
        type's state objects (`ids`)."""
        obj = await self._add_in(machine, type_id, ua.QualifiedName(browse, self.ns_machinery))
        current = await obj.get_child("0:CurrentState")
        state_id = await current.get_child("0:Id")
        self._machines[key] = (current, state_id, ids)
        await self._write_state(key, initial, None)
        return obj

    async def _variable(self, parent: Node, where: tuple[str, ...], var: Var) -> None:
        node = await self.add_variable(parent, where, var)
        self._vars[".".join((*where, var.name))] = (var, node)

    async def add_variable(self, parent: Node, where: tuple[str, ...], var: Var) -> Node:
        """The node of `var` under `parent` (NodeId `<where>.<name>`; AnalogItemType with its
        EngineeringUnits and EURange when it has a unit), not fed from the status reply."""
        typedef = ua.ObjectIds.AnalogItemType if var.unit else ua.ObjectIds.BaseDataVariableType
        node = await self._add(
            parent,
            self._id(*where, var.name),
            ua.QualifiedName(var.name, self.ns),
            typedef,
            nodeclass=ua.NodeClass.Variable,
            datatype=int(var.vtype.value),
            description=var.description,
        )
        if var.unit:
            await node.add_property(
                self._id(*where, var.name, "EngineeringUnits"),
                ua.QualifiedName("EngineeringUnits", 0),
                ua.Variant(eu_information(var.unit), ua.VariantType.ExtensionObject),
                datatype=ua.NodeId(ua.ObjectIds.EUInformation),
            )
            lo, hi = var.eu_range or (0.0, 0.0)
            await node.add_property(
                self._id(*where, var.name, "EURange"),
                ua.QualifiedName("EURange", 0),
                ua.Variant(ua.Range(lo, hi), ua.VariantType.ExtensionObject),
                datatype=ua.NodeId(ua.ObjectIds.Range),
            )
        return node

    async def _add(
        self,
        parent: Node,
        nodeid: ua.NodeId,
        qname: ua.QualifiedName,
        typedef: int | ua.NodeId,
        reftype: int = ua.ObjectIds.HasComponent,
        *,
        nodeclass: ua.NodeClass = ua.NodeClass.Object,
        value: ua.Variant | None = None,
        datatype: int | None = None,
        description: str = "",
    ) -> Node:
        """One node with its type definition and reference from `parent` (asyncua's helpers
        fix both); variables are read-only."""
        item = ua.AddNodesItem()
        item.RequestedNewNodeId, item.BrowseName = nodeid, qname
        item.NodeClass, item.ParentNodeId = nodeclass, parent.nodeid
        item.ReferenceTypeId = ua.NodeId(reftype)
        item.TypeDefinition = typedef if isinstance(typedef, ua.NodeId) else ua.NodeId(typedef)
        attrs: ua.ObjectAttributes | ua.VariableAttributes
        if nodeclass == ua.NodeClass.Variable:
            attrs = ua.VariableAttributes()
            attrs.Value = value if value is not None else ua.Variant(None)
            attrs.DataType = ua.NodeId(datatype or ua.ObjectIds.BaseDataType)
            attrs.ValueRank = ua.ValueRank.Scalar
            attrs.AccessLevel = attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
        else:
            attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(qname.Name)
        if description:
            attrs.Description = ua.LocalizedText(description)
        item.NodeAttributes = attrs
        result = (await self.server.iserver.isession.add_nodes([item]))[0]
        result.StatusCode.check()
        return self.server.get_node(result.AddedNodeId)

    async def apply(self, status: Mapping[str, Any], t: datetime) -> int:
        """Write the values of a status reply (only those that changed, timestamped `t`, the
        service's clock); the number written."""
        written = 0
        for key, (var, node) in self._vars.items():
            last = self._last.get(key)
            dv = data_value(var, lookup(status, var.path), t, last.Value if last else None)
            if last is not None and (last.Value, last.StatusCode) == (dv.Value, dv.StatusCode):
                continue
            await self.server.write_attribute_value(node.nodeid, stamped(dv))
            self._last[key] = dv
            written += 1
        return written + await self._apply_state(status, t)

    async def _apply_state(self, status: Mapping[str, Any], t: datetime) -> int:
        """MachineryItemState from the service's state, MachineryOperationMode from the reply
        (app.line.maintenance_state.operation_mode); the number written."""
        written = 0
        wanted = {"item": ITEM_STATE_OF.get(str(status.get("state"))), "mode": None}
        if "maintenance" in status or status.get("state") in ("starting", "stopped"):
            wanted["mode"] = operation_mode(status)  # (a reply without it: the last kept)
        for key, value in wanted.items():
            if value is None or key not in self._machines or self._now.get(key) == value:
                continue
            await self._write_state(key, value, t)
            written += 1
        return written

    async def _write_state(self, key: str, value: str, t: datetime | None) -> None:
        """CurrentState (the state's name) and its Id (the type's state object)."""
        current, state_id, ids = self._machines[key]
        text = ua.Variant(ua.LocalizedText(value), ua.VariantType.LocalizedText)
        await self.server.write_attribute_value(
            current.nodeid, stamped(ua.DataValue(text, SourceTimestamp=t))
        )
        node_id = ua.Variant(ua.NodeId(ids[value], self.ns_machinery), ua.VariantType.NodeId)
        await self.server.write_attribute_value(
            state_id.nodeid, stamped(ua.DataValue(node_id, SourceTimestamp=t))
        )
        self._now[key] = value


CELL_TYPE_TEXT = (
    "A cell of a robotic visual inspection system that calibrates itself in-line (rvis): a"
    " machine of OPC 40001-1 with rvis's own variables and alarm conditions"
)


async def load_nodesets(server: Server) -> None:
    """Import the official NodeSets (NODESETS, in order) into `server`."""
    for _uri, filename in NODESETS:
        await server.import_xml(str(NODESET_DIR / filename))


@contextlib.contextmanager
def reference_types_fixed(server: Server) -> Iterator[None]:
    """While no reference type is added to `server` (instantiating object types, adding
    objects and variables), each reference type's subtypes found once: asyncua's browse
    walks the HasSubtype tree again for every reference of every node it browses with
    IncludeSubtypes, and instantiating the 16 alarm conditions browses some 7500 times (2.0
    s of a server's start, 0.7 s with this). The same subtypes, so the same browse results."""
    view = server.iserver.view_service
    found: dict[ua.NodeId, frozenset[ua.NodeId]] = {}
    walk = view._get_sub_ref

    def subtypes(ref: ua.NodeId) -> frozenset[ua.NodeId]:
        out = found.get(ref)
        if out is None:
            out = found[ref] = frozenset(walk(ref))
        return out

    view._get_sub_ref = subtypes
    try:
        yield
    finally:
        del view._get_sub_ref


def now_utc() -> datetime:
    """The server's clock (ServerTimestamp): the wall clock, whatever the service's clock."""
    return datetime.now(UTC)


def stamped(dv: ua.DataValue) -> ua.DataValue:
    """`dv` with the ServerTimestamp of now (every value rvis writes carries one)."""
    return dataclasses.replace(dv, ServerTimestamp=now_utc())


def clock_utc(t: float) -> datetime:
    """A service clock time (seconds since the epoch) as an aware UTC datetime."""
    return datetime.fromtimestamp(t, UTC)
