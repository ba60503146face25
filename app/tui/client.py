"""The TUI's connection to the service: the control socket's JSON lines (DESIGN.md section 6).

Two asyncio connections: one subscribed to the service's event stream, one for requests
(replies matched by `id`). `ServiceClient.run()` keeps the connection up: when
the service dies or restarts it reports "disconnected", retries with a bounded back-off and
subscribes again. Nothing here blocks the UI's event loop; nothing here owns a device.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

Event = dict[str, Any]


class ServiceUnavailable(Exception):
    """The service is not connected, or went away before it answered."""


class ServiceClient:
    """Requests and the event stream of one service, reconnecting by itself.

    The socket's `subscribe` turns a connection into an event stream, so there are two: one
    subscribed (its loss is the service's loss) and one for requests, answered in turn.
    on_event(event) receives every streamed event; on_connection(connected, detail) every
    change of the connection. Both are awaited in the caller's loop."""

    def __init__(
        self,
        socket_path: str | Path,
        on_event: Callable[[Event], Awaitable[None]],
        on_connection: Callable[[bool, str], Awaitable[None]],
        *,
        timeout_s: float = 5.0,
        retry_s: tuple[float, float] = (0.2, 2.0),
    ) -> None:
        self.socket_path = Path(socket_path)
        self.on_event, self.on_connection = on_event, on_connection
        self.timeout_s, self.retry_s = timeout_s, retry_s
        self._ids = itertools.count(1)
        self._requests: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None
        self._lock: asyncio.Lock | None = None
        self.connected = False

    async def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command and return the service's reply (`ok` true or false)."""
        if not self.connected:
            raise ServiceUnavailable("not connected to the service")
        self._lock = self._lock or asyncio.Lock()
        async with self._lock:
            try:
                return await asyncio.wait_for(self._exchange(cmd, args), self.timeout_s)
            except (OSError, TimeoutError, EOFError) as exc:
                self._close_requests()
                raise ServiceUnavailable(f"{cmd}: no answer from the service ({exc})") from exc

    async def _exchange(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        if self._requests is None:
            self._requests = await asyncio.open_unix_connection(str(self.socket_path))
        reader, writer = self._requests
        rid = next(self._ids)
        writer.write((json.dumps({"id": rid, "cmd": cmd, "args": args}) + "\n").encode())
        await writer.drain()
        while line := await reader.readline():
            with contextlib.suppress(json.JSONDecodeError):
                msg = json.loads(line)
                if isinstance(msg, dict) and msg.get("id") == rid:
                    return msg
        raise EOFError("the service closed the connection")

    def _close_requests(self) -> None:
        if self._requests is not None:
            self._requests[1].close()
            self._requests = None

    async def run(self) -> None:
        """Connect, subscribe, dispatch; on loss report it and reconnect (until cancelled)."""
        delay = self.retry_s[0]
        while True:
            try:
                reader, writer = await asyncio.open_unix_connection(str(self.socket_path))
            except OSError as exc:
                await self._set_connected(False, f"service not reachable ({exc.strerror})")
                await asyncio.sleep(delay)
                delay = min(2 * delay, self.retry_s[1])
                continue
            delay = self.retry_s[0]
            try:
                await self._session(reader, writer)
            except OSError:
                pass
            finally:
                self.connected = False
                self._close_requests()
                writer.close()
                with contextlib.suppress(OSError):
                    await writer.wait_closed()
            await self._set_connected(False, "connection to the service lost")

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(b'{"id": 0, "cmd": "subscribe"}\n')
        await writer.drain()
        first = await reader.readline()
        if not first:
            return
        self.connected = True
        await self.on_connection(True, "connected")
        while line := await reader.readline():
            try:
                msg = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(msg, dict) and "event" in msg:
                await self.on_event(msg)

    async def _set_connected(self, connected: bool, detail: str) -> None:
        if connected != self.connected or not connected:
            self.connected = connected
            await self.on_connection(connected, detail)
