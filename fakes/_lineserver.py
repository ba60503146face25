"""The asyncio scaffolding shared by the line-based JSON peers (RMI controller, tracker side-car).

A ``LineServer`` runs its listening sockets on a private LoopThread, serves each client with one
task reading lines, and hands every line to the subclass's ``_handle(line, writer)`` (return False
to close that connection). It also keeps the one-shot fault table of the test controls:
``fail_next(name, mode)`` with the transport faults "drop" (close on receipt), "mute" (never
answer), "garble" (answer a line that is not JSON) and "truncate" (half an answer, then close),
or an int error code that the subclass answers with in its own protocol.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Coroutine
from typing import Any, ClassVar, Self, TypeVar

from fakes._loop import LoopThread

T = TypeVar("T")
Mode = str | int


class LineServer:
    """Base of the JSON-lines peers; ``start()`` binds ``port`` (0: ephemeral) on ``host``."""

    terminator: ClassVar[bytes] = b"\n"

    def __init__(self, *, host: str = "127.0.0.1", port: int = 0) -> None:
        self.host, self._want_port = host, port
        self.port = 0
        self._faults: dict[str, Mode] = {}
        self._writers: set[asyncio.StreamWriter] = set()
        self._servers: list[asyncio.Server] = []
        self._loop: LoopThread | None = None

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> Self:
        self._loop = LoopThread(type(self).__name__)
        self._loop.run(self._start())
        return self

    async def _start(self) -> None:
        self.port = await self._listen(self._want_port)

    async def _listen(self, port: int) -> int:
        """Accept clients on another ``port`` (0: ephemeral); returns the port bound."""
        server = await asyncio.start_server(self._serve, self.host, port)
        self._servers.append(server)
        return int(server.sockets[0].getsockname()[1])

    def close(self) -> None:
        if self._loop is not None:
            self._loop.run(self._shutdown())
            self._loop.stop()
            self._loop = None

    async def _shutdown(self) -> None:
        for server in self._servers:
            server.close()
        await asyncio.sleep(0)  # clients accepted but not served yet register their writers
        writers = list(self._writers)
        for writer in writers:
            writer.close()
        for writer in writers:  # let the transports finish closing before the loop stops
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()
        for server in self._servers:
            await server.wait_closed()
        self._servers = []

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- test controls ------------------------------------------------------------------------
    def fail_next(self, name: str, mode: Mode) -> None:
        """Fail the next request called ``name`` (see the module docstring for the modes)."""
        self._faults[name] = mode

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        """Run a coroutine on the server's loop from a test's thread."""
        if self._loop is None:
            coro.close()
            raise RuntimeError(f"{type(self).__name__} is not started")
        return self._loop.run(coro)

    # -- serving ------------------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            while line := await reader.readline():
                if not await self._handle(line, writer):
                    break
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            self._writers.discard(writer)
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()

    async def _handle(self, line: bytes, writer: asyncio.StreamWriter) -> bool:
        """Answer one line; False closes the connection."""
        raise NotImplementedError

    async def _transport_fault(
        self, mode: Mode | None, writer: asyncio.StreamWriter, *, truncated: bytes
    ) -> bool | None:
        """Play a transport fault: whether to keep the connection, or None if ``mode`` is none
        (no fault, or an error code the subclass answers with)."""
        if mode == "drop":
            return False
        if mode == "mute":
            return True
        if mode in ("garble", "truncate"):
            writer.write(b"<html>" + self.terminator if mode == "garble" else truncated)
            await writer.drain()
            return mode == "garble"
        return None

    async def _send(self, writer: asyncio.StreamWriter, msg: dict[str, Any]) -> None:
        if writer.is_closing():
            return
        writer.write(json.dumps(msg).encode() + self.terminator)
        with contextlib.suppress(ConnectionError):
            await writer.drain()
