// A second, independent OPC UA client for rvis's server: node-opcua (Sterfive's Node.js SDK,
// npm `node-opcua-client`), driven by bench/opcua_interop.py, which says how to install it.
//
//     NODE_OPCUA=/path/node_modules/node-opcua-client node bench/opcua_interop.mjs URL MACHINE
//
// It resolves the rvis variables by browse path (TranslateBrowsePathsToNodeIds, namespace URIs
// looked up in the NamespaceArray), reads them, subscribes to Windows and to AlarmConditionType
// events on the Server object (with the ConditionId), and executes the lines it reads on stdin:
// `read`, `ack CODE` (the Acknowledge method with the condition's last EventId), `quit`.
// Everything it sees is one JSON line on stdout.

import readline from "node:readline";
import { pathToFileURL } from "node:url";

const where = process.env.NODE_OPCUA;
const entry = where ? pathToFileURL(`${where}/dist/index.js`).href : "node-opcua-client";
const ua = await import(entry);
const [url, machine] = process.argv.slice(2);
const NAMES = [
  "ServiceState", "Step", "CalibrationVersion", "CalibrationRmsMm", "CalibrationAppliedUtc",
  "PendingCalibration", "Windows", "Overruns", "MeasurementsOk", "MeasurementsRejected",
  "CellTemperatureC", "ActiveAlarms",
];
const FIELDS = [
  "EventId", "ConditionId", "ConditionName", "Severity", "Message", "ActiveState.Id",
  "AckedState.Id", "Retain", "Time", "Comment",
];

const out = (r) => process.stdout.write(JSON.stringify(r) + "\n");
const plain = (v) => (v === null || v === undefined ? null
  : v instanceof Date ? v.toISOString()
  : Buffer.isBuffer(v) ? v.toString("hex")
  : typeof v === "object" && "text" in v ? v.text
  : typeof v === "object" && "toString" in v && v.constructor.name === "NodeId" ? v.toString()
  : v);

const client = ua.OPCUAClient.create({
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 2, initialDelay: 100, maxDelay: 500 },
});
await client.connect(url);
const session = await client.createSession();
const ns = await session.readNamespaceArray();
const rvis = ns.indexOf("urn:rvis:opcua");
const mach = ns.indexOf("http://opcfoundation.org/UA/Machinery/");
const di = ns.indexOf("http://opcfoundation.org/UA/DI/");
const base = `/Objects/${mach}:Machines/${rvis}:${machine}`;
const paths = [
  ...NAMES.map((n) => `${base}/${rvis}:${n}`),
  `${base}/${di}:Identification/${di}:SerialNumber`,
  `${base}/${di}:Identification/${di}:SoftwareRevision`,
  `${base}/${mach}:MachineryItemState/CurrentState`,
];
const found = await session.translateBrowsePath(paths.map((p) => ua.makeBrowsePath("RootFolder", p)));
const ids = found.map((r, i) => {
  if (!r.targets || !r.targets.length) throw new Error(`not found: ${paths[i]} (${r.statusCode})`);
  return r.targets[0].targetId;
});
const labels = [...NAMES, "SerialNumber", "SoftwareRevision", "MachineryItemState"];
out({ k: "resolved", n: ids.length, namespaces: { rvis, mach, di } });

// By the official types only (OPC 40001-1): under Machines (Machinery i=1001), the object with
// a HasAddIn to a MachineIdentificationType (i=1012) and to a MachineryItemState_StateMachineType
// (i=1002); Identification's properties and the state read through those nodes.
async function children(nodeId, referenceTypeId) {
  const r = await session.browse({
    nodeId, referenceTypeId, browseDirection: ua.BrowseDirection.Forward,
    includeSubtypes: true, resultMask: 63,
  });
  return r.references || [];
}
const typeOf = (ref) => ref.typeDefinition.toString();
const machineType = (i) => ua.coerceNodeId(`ns=${mach};i=${i}`).toString();
const official = { k: "official", machines: [] };
for (const m of await children(ua.coerceNodeId(`ns=${mach};i=1001`), "Organizes")) {
  const addIns = await children(m.nodeId, "HasAddIn");
  const ident = addIns.find((r) => typeOf(r) === machineType(1012));
  const state = addIns.find((r) => typeOf(r) === machineType(1002));
  if (!ident || !state) continue;
  const entry = { browseName: m.browseName.toString(), identification: {} };
  for (const p of await children(ident.nodeId, "HasProperty")) {
    const dv = await session.read({ nodeId: p.nodeId, attributeId: ua.AttributeIds.Value });
    entry.identification[p.browseName.name] = plain(dv.value.value);
  }
  const [cs] = await session.translateBrowsePath([ua.makeBrowsePath(state.nodeId, "/CurrentState")]);
  const csId = cs.targets[0].targetId;
  const [idPath] = await session.translateBrowsePath([ua.makeBrowsePath(csId, ".Id")]);
  const current = await session.read({ nodeId: csId, attributeId: ua.AttributeIds.Value });
  const stateId = await session.read({ nodeId: idPath.targets[0].targetId, attributeId: ua.AttributeIds.Value });
  const stateNode = await session.read({ nodeId: stateId.value.value, attributeId: ua.AttributeIds.BrowseName });
  entry.currentState = plain(current.value.value);
  entry.stateId = stateId.value.value.toString();
  entry.stateNode = stateNode.value.value.toString();
  entry.identificationType = typeOf(ident);
  entry.stateType = typeOf(state);
  official.machines.push(entry);
}
const versions = {};
for (const n of await children(ua.resolveNodeId("Server_Namespaces"), "HasComponent")) {
  const [uri, version] = await session.translateBrowsePath([
    ua.makeBrowsePath(n.nodeId, ".NamespaceUri"), ua.makeBrowsePath(n.nodeId, ".NamespaceVersion"),
  ]);
  if (!uri.targets || !version.targets) continue;
  const u = await session.read({ nodeId: uri.targets[0].targetId, attributeId: ua.AttributeIds.Value });
  const v = await session.read({ nodeId: version.targets[0].targetId, attributeId: ua.AttributeIds.Value });
  versions[u.value.value] = v.value.value;
}
official.namespaceVersions = versions;
out(official);

async function read() {
  const dvs = await session.read(ids.map((nodeId) => ({ nodeId, attributeId: ua.AttributeIds.Value })));
  const values = {};
  dvs.forEach((dv, i) => {
    values[labels[i]] = { value: plain(dv.value.value), status: dv.statusCode.name };
  });
  out({ k: "read", values });
}

const sub = await session.createSubscription2({
  requestedPublishingInterval: 50, requestedMaxKeepAliveCount: 20, requestedLifetimeCount: 600,
  maxNotificationsPerPublish: 100, publishingEnabled: true, priority: 1,
});
const windows = ua.ClientMonitoredItem.create(
  sub, { nodeId: ids[NAMES.indexOf("Windows")], attributeId: ua.AttributeIds.Value },
  { samplingInterval: 0, queueSize: 10, discardOldest: true }, ua.TimestampsToReturn.Both,
);
windows.on("changed", (dv) => out({ k: "data", name: "Windows", v: dv.value.value, src: plain(dv.sourceTimestamp) }));

const last = {}; // condition name -> { eventId, conditionId }
const events = ua.ClientMonitoredItem.create(
  sub, { nodeId: ua.resolveNodeId("Server"), attributeId: ua.AttributeIds.EventNotifier },
  { samplingInterval: 0, queueSize: 100, discardOldest: true,
    filter: ua.constructEventFilter(FIELDS, ua.ofType("AlarmConditionType")) },
  ua.TimestampsToReturn.Both,
);
events.on("changed", (fields) => {
  const e = {};
  FIELDS.forEach((f, i) => { e[f] = fields[i].value; });
  last[e.ConditionName] = { eventId: e.EventId, conditionId: e.ConditionId };
  const shown = {};
  for (const f of FIELDS) shown[f] = plain(e[f]);
  out({ k: "event", ...shown });
});
await new Promise((resolve) => setTimeout(resolve, 200)); // the monitored items created
out({ k: "ready" });

const lines = readline.createInterface({ input: process.stdin });
for await (const line of lines) {
  const [cmd, arg] = line.trim().split(/\s+/);
  if (cmd === "read") await read();
  else if (cmd === "ack") {
    const c = last[arg];
    const result = await session.call({
      objectId: c.conditionId,
      methodId: ua.resolveNodeId("AcknowledgeableConditionType_Acknowledge"),
      inputArguments: [
        { dataType: ua.DataType.ByteString, value: c.eventId },
        { dataType: ua.DataType.LocalizedText, value: { text: "acknowledged from node-opcua" } },
      ],
    });
    out({ k: "ack", code: arg, status: result.statusCode.name });
  } else if (cmd === "quit") break;
}
await sub.terminate();
await session.close();
await client.disconnect();
out({ k: "done" });
