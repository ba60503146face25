"""The OPC UA server's own process (`python -m app.line.opcua.child`), started and supervised by
app.line.opcua.server.OpcUaServer in the service's process; nothing else runs it.

It talks to the service only through its standard input and output, one JSON object per line:

    in   {"config": {...}}                      first: the settings, state directory, spheres
         {"alarm": {...}, "t": T}                one alarm change (id, code, state after it,
                                                priority, message, comment, user; `change`:
                                                the event), in the order the service made them
         {"body": {...}, "t": T[, "replay": true]}   a body's result (app.line.opcua.results),
                                                in order with the alarm changes; a replay (the
                                                last body, to a restarted process): no event
         {"status": <status reply>, "t": T, "alarms_current": B}   the service's status after
                                                events (time T); B: its alarms reflect no change
                                                not sent yet (the conditions are set from them)
         {"reply": N, "error": null | "..."}    the service's answer to acknowledge N
         {"stop": true}                         publish what is queued, flush, exit (also EOF)
    out  {"ready": true} | {"error": "...", "field": ...}   once, after the start
         {"log": LEVEL, "msg": "..."}           its log records (the service logs them)
         {"ack": N, "alarm": ID, "user": ..., "comment": ...}   an OPC UA client's Acknowledge

So it has no say over the cycle: the service reads only `ack` requests from it (and only with
`[opcua] allow_ack`). A peer's data is bounded by the transport guard (app.line.opcua.guard),
the incoming statuses by INBOX (the service's side then blocks only its feed thread). SIGINT
and SIGTERM are ignored: a terminal's Ctrl-C or a supervisor's stop reaches the whole process
group, and the service stops this process itself after publishing `stopped`. It runs at a lower
priority (NICE) than the service: under any load the cycle comes first.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import queue
import signal
import sys
import threading
from datetime import datetime
from types import SimpleNamespace
from typing import IO, TYPE_CHECKING, Any, cast

from app.config.endpoint import FIELD, cannot_listen
from app.errors import InputError
from app.line.statedir import StateDir

if TYPE_CHECKING:
    from asyncua import Server

    from app.config.line import OpcUaSettings
    from app.line.opcua.alarms import Conditions
    from app.line.opcua.results import BodyResults
    from app.line.opcua.space import AddressSpace

NICE = 5  # below the service (0): the cycle first
INBOX = 64  # messages from the service waiting here, at most
ACK_TIMEOUT_S = 60.0  # an ack waits for the end of a running window at most this long
FLUSH_TIMEOUT_S = 2.0  # the last values' publishing at the end, at most
FLUSH_POLL_S = 0.005
REFRESH_SEVERITY = 100  # of the RefreshStart/End events around a ConditionRefresh
_EOF: dict[str, Any] = {"stop": True}

log = logging.getLogger("rvis.line.opcua")


class Out:
    """The line-oriented channel to the service (thread-safe; a gone service is ignored)."""

    def __init__(self, stream: IO[bytes]) -> None:
        self.stream = stream
        self._lock = threading.Lock()

    def send(self, obj: dict[str, Any]) -> None:
        data = (json.dumps(obj, default=str) + "\n").encode()
        with self._lock, contextlib.suppress(OSError, ValueError):
            self.stream.write(data)
            self.stream.flush()


class ToService(logging.Handler):
    """Log records to the service (which logs them as its own): the message only, and for
    asyncua's records not even an exception's traceback (one line per record)."""

    def __init__(self, out: Out) -> None:
        super().__init__(logging.INFO)
        self.out = out

    def emit(self, record: logging.LogRecord) -> None:
        try:
            msg = record.getMessage()
            if record.exc_info and record.exc_info[1] is not None:
                exc = record.exc_info[1]
                msg = f"{msg}: {type(exc).__name__}: {exc}"
            if not record.name.startswith("rvis"):
                msg = f"{record.name}: {msg}"
            self.out.send({"log": record.levelno, "msg": msg[:2000]})
        except Exception:
            self.handleError(record)


def _read_inbox(stream: IO[bytes], inbox: queue.Queue[dict[str, Any]]) -> None:
    """The service's lines into the bounded inbox (blocks the service's writer when full)."""
    for raw in stream:
        try:
            msg = json.loads(raw)
        except ValueError:
            log.warning("OPC UA server: an unreadable line from the service ignored")
            continue
        if isinstance(msg, dict):
            inbox.put(msg)
    inbox.put(_EOF)  # the service is gone (or closed the pipe): stop


async def flush(server: Server, timeout_s: float) -> bool:
    """Wait until every subscription has sent what was triggered (the last values and events
    reach the clients before the server goes); False when `timeout_s` passed first (a client
    that sends no Publish request)."""
    subscriptions = server.iserver.subscription_service.subscriptions
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while any(s._triggered_datachanges or s._triggered_events for s in subscriptions.values()):
        if loop.time() > deadline:
            return False
        await asyncio.sleep(FLUSH_POLL_S)  # asyncua signals no "sent"; its publish loop runs
    return True


class Child:
    """The server of one configuration, fed from the inbox."""

    def __init__(self, config: dict[str, Any], out: Out, inbox: queue.Queue[dict[str, Any]]):
        # the settings as read by the service (app.config is not imported here: it brings the
        # numerics, a second or more and 100 MB of this process, for one small dataclass)
        self.settings = cast("OpcUaSettings", SimpleNamespace(**config["settings"]))
        self.paths = StateDir(config["state_dir"])
        self.spheres: list[str] = list(config["spheres"])
        self.revision = str(config["software_revision"])
        self.app_uri = str(config["application_uri"])
        self.t = float(config.get("t", 0.0))  # the service's clock at the start
        self.out, self.inbox = out, inbox
        self.space: AddressSpace | None = None
        self.conditions: Conditions | None = None
        self.results: BodyResults | None = None
        self._acks: dict[int, asyncio.Future[str | None]] = {}
        self._ack_ids = 0

    async def serve(self) -> int:
        try:
            server = await self._build()
            await self._listen(server)
        except InputError as exc:
            self.out.send({"error": exc.reason, "field": exc.field, "file": exc.file})
            return 2
        except OSError as exc:  # the state directory's certificate folder, the network
            reason = f"the OPC UA server cannot start at {self.settings.endpoint}: {exc}"
            self.out.send({"error": reason, "field": FIELD})
            return 2
        try:
            msg = await self._next()  # the status (and what _next read behind it)
            await self._handle(msg)
            self.out.send({"ready": True, "pid": os.getpid()})
            while "stop" not in msg:
                msg = await self._next()
                await self._handle(msg)
            await flush(server, FLUSH_TIMEOUT_S)
        finally:
            await server.stop()
        return 0

    async def _handle(self, msg: dict[str, Any]) -> None:
        if "status" in msg:
            await self._apply(msg)
        elif "alarm" in msg:
            await self._change(msg)
        elif "body" in msg:
            await self._body(msg)
        elif "reply" in msg:
            self._replied(msg)

    async def _next(self) -> dict[str, Any]:
        """The next message; of statuses queued one after another, the last (coalesced)."""
        msg = await asyncio.to_thread(self.inbox.get)
        while "status" in msg:
            try:
                after = self.inbox.get_nowait()
            except queue.Empty:
                break
            if "status" not in after:
                await self._apply(msg)
                return after
            msg = {**after, "t": max(float(after.get("t", 0.0)), float(msg.get("t", 0.0)))}
        return msg

    async def _build(self) -> Server:
        from asyncua import Server

        from app.line.opcua import guard, security
        from app.line.opcua.alarms import Conditions
        from app.line.opcua.results import BodyResults
        from app.line.opcua.space import AddressSpace, clock_utc, reference_types_fixed

        s = self.settings
        server = Server(user_manager=security.user_manager(s, self.paths))
        server.iserver.bind_condition_methods = REFRESH_SEVERITY  # ConditionRefresh(2)
        await server.init()
        server.set_endpoint(s.endpoint)
        server.set_server_name(f"rvis {s.machine_name}")
        await server.set_application_uri(self.app_uri)
        await security.secure(server, s, self.paths, self.app_uri)
        self.space = AddressSpace(server, s)
        machine = await self.space.build(sorted(self.spheres), self.revision, clock_utc(self.t))
        ack = self._acknowledge if s.allow_ack else None
        self.conditions = Conditions(server, self.space.ns, machine, ack)
        self.results = BodyResults(server, self.space)
        with reference_types_fixed(server):  # objects and variables only from here
            await self.conditions.setup()  # (the machine an event notifier: the results' too)
            await self.results.setup(clock_utc(self.t))
        guard.install(server)
        return server

    async def _listen(self, server: Server) -> None:
        try:
            await server.start()
        except OSError as exc:
            raise InputError(cannot_listen(self.settings.endpoint, exc), field=FIELD) from exc

    async def _apply(self, msg: dict[str, Any]) -> None:
        """One status reply into the address space and the alarm conditions."""
        from app.line.opcua.space import clock_utc

        assert self.space is not None and self.conditions is not None
        status: dict[str, Any] = msg["status"]
        when: datetime = clock_utc(float(msg.get("t", 0.0)))
        try:
            await self.space.apply(status, when)
            if msg.get("alarms_current", True):  # else its alarms may be ahead of the events
                await self.conditions.sync(list(status.get("alarms", [])), when)
        except Exception as exc:  # a status this version cannot read: the next one may
            log.warning("OPC UA update skipped: %s: %s", type(exc).__name__, exc)

    async def _change(self, msg: dict[str, Any]) -> None:
        """One alarm change into its condition (an OPC UA event)."""
        from app.line.opcua.space import clock_utc

        assert self.conditions is not None
        try:
            await self.conditions.apply(msg["alarm"], clock_utc(float(msg.get("t", 0.0))))
        except Exception as exc:  # a change this version cannot read
            log.warning("OPC UA alarm event skipped: %s: %s", type(exc).__name__, exc)

    async def _body(self, msg: dict[str, Any]) -> None:
        """One body's result: its event (unless a replay) and the LastBody variables."""
        from app.line.opcua.space import clock_utc

        assert self.results is not None
        try:
            t = clock_utc(float(msg.get("t", 0.0)))
            await self.results.publish(msg["body"], t, replay=bool(msg.get("replay")))
        except Exception as exc:  # a result this version cannot read
            log.warning("OPC UA body result skipped: %s: %s", type(exc).__name__, exc)

    async def _acknowledge(self, alarm_id: int, who: str, comment: str) -> str | None:
        """The service's audited `ack` (asked over the channel; its reply awaited)."""
        self._ack_ids += 1
        n = self._ack_ids
        future: asyncio.Future[str | None] = asyncio.get_running_loop().create_future()
        self._acks[n] = future
        self.out.send({"ack": n, "alarm": alarm_id, "user": who, "comment": comment})
        try:
            return await asyncio.wait_for(future, ACK_TIMEOUT_S)
        except TimeoutError:
            return f"no reply from the service in {ACK_TIMEOUT_S:g} s"
        finally:
            self._acks.pop(n, None)

    def _replied(self, msg: dict[str, Any]) -> None:
        future = self._acks.get(int(msg["reply"]))
        if future is not None and not future.done():
            error = msg.get("error")
            future.set_result(None if error is None else str(error))


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    with contextlib.suppress(OSError):
        os.nice(NICE)
    out = Out(sys.stdout.buffer)
    sys.stdout = sys.stderr  # a stray print must not break the channel
    from app.line.opcua.refusals import QuietAsyncua

    handler = ToService(out)
    handler.addFilter(QuietAsyncua())  # a peer's connections cannot flood the service's log
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.INFO)
    logging.getLogger("asyncua").setLevel(logging.WARNING)
    # the NodeSets' import warns of a DI structure it cannot classify, harmlessly, each start
    logging.getLogger("asyncua.common.xmlimporter").setLevel(logging.ERROR)
    first = sys.stdin.buffer.readline()
    if not first:
        return 0
    config = json.loads(first)["config"]
    inbox: queue.Queue[dict[str, Any]] = queue.Queue(INBOX)
    threading.Thread(
        target=_read_inbox, args=(sys.stdin.buffer, inbox), name="rvis-opcua-inbox", daemon=True
    ).start()
    try:
        return asyncio.run(Child(config, out, inbox).serve())
    except Exception as exc:
        log.error("OPC UA server failed: %s: %s", type(exc).__name__, exc)
        out.send({"error": f"{type(exc).__name__}: {exc}", "internal": True})
        return 1


if __name__ == "__main__":
    sys.exit(main())
