"""The cell's state over OPC UA (DESIGN.md section 8, docs/opcua.md): an asyncua server in a
process of its own, fed by the service's events, never polling it, with no say over the cycle.

endpoint   the endpoint URL's checks and the security policies (no asyncua import: the cell
           file's check uses it)
server     in the service's process: starts, feeds and supervises the server process
child      the server process (`python -m app.line.opcua.child`): builds and serves
guard      the transport guard: oversized or malformed messages get ERR, never buffered
security   the server's certificate, the trusted clients, identities and what a client may do
space      the address space: the OPC 40001-1 machine (the official NodeSets) and rvis's variables
alarms     the service's alarms as Alarms & Conditions (AlarmConditionType), acknowledge
results    the bodies' results: a BodyResultEventType event per body, the LastBody variables
feed       in the service's process: the queue of events to the server process (alarm and body
           events in order, the others merged; drops counted)
"""

#: the name the feed's queue subscribes to the event bus with (its losses: `rvis status`)
FEED_NAME = "opcua"
