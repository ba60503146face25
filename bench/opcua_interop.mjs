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
  "AckedState.Id", "Retain", "Time",
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
