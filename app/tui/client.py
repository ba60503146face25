"""The TUI's connection to the service: the control socket's JSON lines (DESIGN.md section 6).

One asyncio connection carries both the replies to requests (matched by `id`) and, after a
`subscribe`, the service's event stream. `ServiceClient.run()` keeps the connection up: when
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
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._writer: asyncio.StreamWriter | None = None
        self.connected = False

    async def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command and return the service's reply (`ok` true or false)."""
        writer = self._writer
        if writer is None or not self.connected:
            raise ServiceUnavailable("not connected to the service")
        rid = next(self._ids)
        future: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[rid] = future
        try:
            writer.write((json.dumps({"id": rid, "cmd": cmd, **args}) + "\n").encode())
            await writer.drain()
            return await asyncio.wait_for(future, self.timeout_s)
        except (OSError, TimeoutError) as exc:
            raise ServiceUnavailable(f"{cmd}: no answer from the service ({exc})") from exc
        finally:
            self._pending.pop(rid, None)

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
            self._writer = writer
            try:
                await self._session(reader, writer)
            finally:
                self._writer = None
                self._fail_pending()
                writer.close()
                with contextlib.suppress(OSError):
                    await writer.wait_closed()
            await self._set_connected(False, "connection to the service lost")

    async def _session(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connected = True
        reading = asyncio.create_task(self._read(reader))
        try:
            await self.request("subscribe")
            await self.on_connection(True, "connected")
            await reading
        except ServiceUnavailable:
            reading.cancel()
        finally:
            self.connected = False

    async def _read(self, reader: asyncio.StreamReader) -> None:
        while line := await reader.readline():
            try:
                msg = json.loads(line)
            except json.JSONDecodeError:
                continue
            if not isinstance(msg, dict):
                continue
            rid = msg.get("id")
            future = self._pending.get(rid) if isinstance(rid, int) else None
            if future is not None and not future.done():
                future.set_result(msg)
            elif "event" in msg:
                await self.on_event(msg)

    async def _set_connected(self, connected: bool, detail: str) -> None:
        if connected != self.connected or not connected:
            self.connected = connected
            await self.on_connection(connected, detail)

    def _fail_pending(self) -> None:
        for future in self._pending.values():
            if not future.done():
                future.set_exception(ServiceUnavailable("the service went away"))
