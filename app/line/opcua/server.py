"""The OPC UA server of the service: its own thread and event loop, fed by the service's events.

    with OpcUaServer(service):          # app.line.launch.serving() when [opcua] enabled
        service.run()

Two threads, neither of which the service ever waits for:
- `rvis-opcua`: asyncua's event loop (the server, its clients, the alarm conditions);
- `rvis-opcua-feed`: blocks on a subscription to the service's event bus; after an event (and
  the others queued behind it) it takes one status reply, exactly what `rvis status` answers,
  and hands it to the loop, which writes the variables that changed (timestamped with the
  service's clock: the event's time) and triggers the alarm events. While the loop works, the
  events queue up in the subscription (bounded; the oldest dropped first: the next status
  reply carries their effect), so a slow OPC UA side costs the service nothing.

`start()` returns once the server listens (InputError when it cannot: exit 2 at `rvis run`).
An OPC UA acknowledge is the service's `ack` command (queued and audited like the socket's).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import socket
import threading
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any

from app.config.line import OpcUaSettings
from app.errors import InputError
from app.line.opcua.endpoint import endpoint_problem, split_endpoint
from app.line.statedir import StateDir

if TYPE_CHECKING:
    from asyncua import Server

    from app.line.opcua.alarms import Conditions
    from app.line.opcua.space import AddressSpace
    from app.line.service import Service

log = logging.getLogger("rvis.line.opcua")
START_TIMEOUT_S = 60.0
ACK_TIMEOUT_S = 60.0  # an ack waits for the end of a running window at most this long
_STOP = {"event": "__opcua_stop__"}
FLUSH_TIMEOUT_S = 2.0  # the last values' publishing at the end, at most
FLUSH_POLL_S = 0.005
REFRESH_SEVERITY = 100  # of the RefreshStart/End events around a ConditionRefresh


async def flush(server: Server, timeout_s: float) -> bool:
    """Wait until every subscription has sent what was triggered (the last values and events
    reach the clients before the server goes); False when `timeout_s` passed first (a client
    that sends no Publish request)."""
    subscriptions = server.iserver.subscription_service.subscriptions
    deadline = asyncio.get_running_loop().time() + timeout_s
    while any(s._triggered_datachanges or s._triggered_events for s in subscriptions.values()):
        if asyncio.get_running_loop().time() > deadline:
            return False
        await asyncio.sleep(FLUSH_POLL_S)  # asyncua signals no "sent"; its publish loop runs
    return True


def application_uri(settings: OpcUaSettings) -> str:
    """The server's ApplicationUri (its certificate names it): host and machine."""
    return f"urn:rvis:{socket.gethostname()}:{settings.machine_name}".replace(" ", "-")


def _check_endpoint(settings: OpcUaSettings) -> None:
    """InputError when the endpoint is not allowed or its port is taken (at once: building
    the server takes a second or two)."""
    reason = endpoint_problem(settings.endpoint, settings.security_policy)
    if reason:
        raise InputError(reason, field="[opcua] endpoint")
    host, port = split_endpoint(settings.endpoint)
    try:
        socket.create_server((host, port)).close()
    except OSError as exc:
        raise InputError(
            f"cannot listen at {settings.endpoint}: {exc.strerror or exc}",
            field="[opcua] endpoint",
        ) from exc


class OpcUaServer:
    """The OPC UA server publishing `service` (settings: service.settings.opcua)."""

    def __init__(self, service: Service, settings: OpcUaSettings | None = None) -> None:
        self.service = service
        self.settings = settings or service.settings.opcua
        self.paths = StateDir(service.settings.state_dir)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.server: Server | None = None
        self.space: AddressSpace | None = None
        self.conditions: Conditions | None = None
        self._last_status: dict[str, Any] = {}
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stopping: asyncio.Event | None = None
        self._stopped_published = False
        self._events = service.bus.subscribe()
        self._thread = threading.Thread(target=self._run, name="rvis-opcua", daemon=True)
        self._feed = threading.Thread(target=self._feed_loop, name="rvis-opcua-feed", daemon=True)

    # -- life cycle ------------------------------------------------------------------------
    def start(self) -> OpcUaServer:
        try:
            _check_endpoint(self.settings)
        except InputError:
            self.service.bus.unsubscribe(self._events)
            raise
        self._thread.start()
        if not self._ready.wait(START_TIMEOUT_S):
            self._error = TimeoutError(f"not listening after {START_TIMEOUT_S:g} s")
        if self._error is not None:
            self.stop()
            error = self._error
            if isinstance(error, OSError | TimeoutError):  # the network, the state directory
                raise InputError(
                    f"the OPC UA server cannot listen at {self.settings.endpoint}: {error}",
                    field="[opcua] endpoint",
                ) from error
            raise error  # InputError as it is; anything else is an internal error
        self._feed.start()
        log.info("OPC UA server listening at %s", self.settings.endpoint)
        return self

    def stop(self) -> None:
        """Stop the server; when the service has stopped, its `stopped` state (and
        MachineryItemState NotAvailable) is published and sent to the subscribers first."""
        self.service.bus.unsubscribe(self._events)
        self._events.offer(_STOP)  # never blocks: a full queue loses its oldest event
        if self._feed.is_alive():
            self._feed.join(10.0)
        if self.service.state.value == "stopped" and not self._stopped_published:
            self._publish(self.service.clock.time(), stopped=True)
        if self.loop is not None and self._stopping is not None and self._thread.is_alive():
            self.loop.call_soon_threadsafe(self._stopping.set)
        if self._thread.is_alive():
            self._thread.join(30.0)

    def __enter__(self) -> OpcUaServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the event loop's thread -------------------------------------------------------------
    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:
            if self._ready.is_set():
                raise  # after start: the service's thread hook alarms it (FAULT, restart)
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        server = await self._build()
        try:
            await server.start()
        except OSError as exc:
            raise InputError(
                f"cannot listen at {self.settings.endpoint}: {exc.strerror or exc}",
                field="[opcua] endpoint",
            ) from exc
        try:
            self._last_status = self.service.status()
            await self._apply(self._last_status, self.service.clock.time())
            self._ready.set()
            await self._stopping.wait()
            await flush(server, FLUSH_TIMEOUT_S)
        finally:
            await server.stop()

    async def _build(self) -> Server:
        from asyncua import Server

        from app.line.opcua import security
        from app.line.opcua.alarms import Conditions
        from app.line.opcua.space import AddressSpace
        from app.meta import software_revision

        s = self.settings
        self.server = server = Server(user_manager=security.user_manager(s, self.paths))
        server.iserver.bind_condition_methods = REFRESH_SEVERITY  # ConditionRefresh(2)
        await server.init()
        server.set_endpoint(s.endpoint)
        server.set_server_name(f"rvis {s.machine_name}")
        await server.set_application_uri(application_uri(s))
        await security.secure(server, s, self.paths, application_uri(s))
        self.space = AddressSpace(server, s)
        machine = await self.space.build(sorted(self.service.spheres), software_revision())
        ack = self._acknowledge if s.allow_ack else None
        self.conditions = Conditions(server, self.space.ns, machine, ack)
        await self.conditions.setup()
        return server

    async def _apply(self, status: dict[str, Any], t: float) -> None:
        """One status reply into the address space and the alarm conditions."""
        from app.line.opcua.space import clock_utc

        assert self.space is not None and self.conditions is not None
        when = clock_utc(t)
        await self.space.apply(status, when)
        await self.conditions.sync(list(status.get("alarms", [])), when)

    async def _acknowledge(self, alarm_id: int, who: str, comment: str) -> str | None:
        """The service's audited `ack` (uid: none; the audit names OPC UA and the user)."""
        args = {"alarm": alarm_id, "via": "opcua", "user": who, "comment": comment}
        future = self.service.request("ack", args)
        try:
            reply = await asyncio.wait_for(asyncio.wrap_future(future), ACK_TIMEOUT_S)
        except TimeoutError:
            return f"no reply from the service in {ACK_TIMEOUT_S:g} s"
        return None if reply.get("ok") else str(reply.get("error", "refused"))

    # -- the feed's thread -------------------------------------------------------------------
    def _feed_loop(self) -> None:
        while True:
            batch = [self._events.get()]
            with contextlib.suppress(queue.Empty):
                while True:
                    batch.append(self._events.get_nowait())
            events = [e for e in batch if e is not _STOP]
            if events:  # `stopped` too when it came with the end (the service ended first)
                stopped = any(e["event"] == "stopped" for e in events)
                self._publish(max(float(e.get("t", 0.0)) for e in events), stopped)
            if len(events) < len(batch):
                return

    def _publish(self, t: float, stopped: bool = False) -> None:
        """The service's status now, applied in the loop (waited for: the feed's pace is the
        OPC UA side's); a failure is logged, never the service's. Once the service has
        stopped (its database closing) the last status is published as `stopped`."""
        loop = self.loop
        if loop is None:
            return
        try:
            if stopped:
                status = {**self._last_status, "state": "stopped", "step": "stopped"}
                self._stopped_published = True
            else:
                status = self._last_status = self.service.status()
            done: Future[None] = asyncio.run_coroutine_threadsafe(self._apply(status, t), loop)
            done.result(30.0)
        except Exception as exc:  # the service stopping (database closed), a slow loop
            ending = self.service.state.value in ("stopped", "fault")
            log.log(
                logging.DEBUG if ending else logging.WARNING,
                "OPC UA update skipped: %s: %s",
                type(exc).__name__,
                exc,
            )
