"""The cell's state over OPC UA (DESIGN.md section 8, docs/opcua.md): an asyncua server inside
the service, fed by the service's events, never polling it.

endpoint   the endpoint URL's checks and the security policies (no asyncua import: the cell
           file's check uses it)
security   the server's certificate, the trusted clients, identities and what a client may do
space      the address space: the machine (OPC 40001-1 subset) and rvis's variables
alarms     the service's alarms as Alarms & Conditions (AlarmConditionType), acknowledge
server     the server's thread and event loop, fed from the service's event bus
"""
