"""The OPC UA server's transport guard (docs/opcua.md "Isolation"): what a network peer sends is
checked at the message header, before asyncua buffers or parses it.

asyncua 2.1.0's binary server appends every byte a connection sends to one buffer until the
message its header announces is complete, whatever size the header claims (a header claiming
4 GB keeps a connection buffering until its activation timeout, at a cost that grows with the
buffer), and a body it cannot decode ends in a logged traceback with no reply. `GuardedProtocol`
reads the 8-byte header (OPC 10000-6, 7.1.2) first and refuses, with the protocol's ERR message
and one log line, then closes the connection:

- a message type a server does not receive, or a first message that is not a Hello
  (Bad_TcpMessageTypeInvalid);
- a chunk larger than the negotiated receive buffer (a Hello: HELLO_MAX_BYTES, its endpoint URL
  at most 4096 bytes) or smaller than its header (Bad_TcpMessageTooLarge);
- a message asyncua cannot decode or process (Bad_DecodingError), instead of its traceback.

So a connection holds at most one chunk (64 KiB by default) here and RECEIVE_BUFFER_BYTES in
the kernel, the messages it assembles are bounded by `limits()`, and the connections by
MAX_CONNECTIONS. Refusals are logged at most once
per LOG_EVERY_S per peer host (with the number refused meanwhile), so a flood cannot flood the
log. `install(server)` puts the guard in front of an asyncua Server before its start.
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket
import struct
import time
from typing import Any

from asyncua import Server, ua
from asyncua.common.connection import TransportLimits
from asyncua.common.utils import Buffer
from asyncua.server import binary_server_asyncio
from asyncua.server import server as server_module
from asyncua.ua.ua_binary import header_from_binary, uatcp_to_binary

log = logging.getLogger("rvis.line.opcua")

HEADER = struct.Struct("<3scI")  # MessageType, ChunkType, MessageSize (OPC 10000-6, 7.1.2)
HELLO_MAX_BYTES = 8 + 5 * 4 + 4 + 4096  # header, 5 UInt32, the endpoint URL (<= 4096 bytes)
CHUNK_BYTES = 65535  # the receive and send buffers (asyncua's default)
MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # a request of rvis's clients is a few kB
RECEIVE_BUFFER_BYTES = 2 * 65536  # two chunks in flight (the kernel's, per connection)
MAX_CONNECTIONS = 64  # a cell's clients: SCADA, MES, a historian, engineering tools
ACTIVATION_S = 10.0  # a connection without an activated session is closed after this
LOG_EVERY_S = 10.0
SECURE = (b"OPN", b"MSG", b"CLO")
CHUNK_TYPES = (b"F", b"C", b"A")
MIN_SECURE_BYTES = 12  # header and SecureChannelId


def limits() -> TransportLimits:
    """The transport limits offered to every client."""
    return TransportLimits(
        max_recv_buffer=CHUNK_BYTES,
        max_send_buffer=CHUNK_BYTES,
        max_chunk_count=math.ceil(MAX_MESSAGE_BYTES / CHUNK_BYTES),
        max_message_size=MAX_MESSAGE_BYTES,
    )


class RefusalLog:
    """One log line per peer host per LOG_EVERY_S (with how many were refused meanwhile)."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, int]] = {}

    def note(self, host: str, text: str) -> None:
        now = time.monotonic()
        last, quiet = self._last.get(host, (-math.inf, 0))
        if now - last < LOG_EVERY_S:
            self._last[host] = (last, quiet + 1)
            return
        more = f" ({quiet} more refused from {host} in the last {LOG_EVERY_S:g} s)" if quiet else ""
        log.warning("OPC UA connection from %s refused: %s%s", host, text, more)
        self._last[host] = (now, 0)
        if len(self._last) > 1024:  # many hosts: forget the quiet ones
            self._last = {h: v for h, v in self._last.items() if now - v[0] < LOG_EVERY_S}


REFUSALS = RefusalLog()


def error_message(code: int, reason: str) -> bytes:
    """An ERR message (OPC 10000-6, 7.1.2.5)."""
    return bytes(
        uatcp_to_binary(ua.MessageType.Error, ua.ErrorMessage(ua.StatusCode(code), reason))
    )


class GuardedProtocol(binary_server_asyncio.OPCUAProtocol):
    """asyncua's connection protocol with the header checked before any buffering."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._pending = bytearray()
        self._hello = False
        self._refused = False

    def data_received(self, data: bytes) -> None:
        if self._refused or self.transport is None:
            return
        self._pending += data
        while len(self._pending) >= HEADER.size:
            mtype, ctype, size = HEADER.unpack_from(self._pending)
            problem = self._problem(mtype, ctype, size)
            if problem is not None:
                self.refuse(*problem)
                return
            if len(self._pending) < size:
                return  # at most one chunk waits here
            frame = Buffer(bytes(self._pending[:size]))
            del self._pending[:size]
            header = header_from_binary(frame)
            self._hello = True
            try:
                self.messages.put_nowait((header, frame))
            except asyncio.QueueFull:
                self.refuse(ua.StatusCodes.BadTcpServerTooBusy, "too many messages queued")
                return

    def _problem(self, mtype: bytes, ctype: bytes, size: int) -> tuple[int, str] | None:
        """Why a chunk with this header is refused (None: it is not)."""
        invalid = ua.StatusCodes.BadTcpMessageTypeInvalid
        if not self._hello:
            if mtype != b"HEL" or ctype != b"F":
                return invalid, f"expected a Hello, got message type {mtype!r}{ctype!r}"
            limit, smallest = HELLO_MAX_BYTES, HEADER.size
        else:
            if mtype not in SECURE or ctype not in CHUNK_TYPES:
                return invalid, f"message type {mtype!r}{ctype!r} is not one a server receives"
            limit, smallest = self._chunk_limit(), MIN_SECURE_BYTES
        if size > limit or size < smallest:
            return (
                ua.StatusCodes.BadTcpMessageTooLarge,
                f"a {mtype.decode('latin-1')} chunk of {size} bytes (limit {limit})",
            )
        return None

    def _chunk_limit(self) -> int:
        """The receive buffer negotiated with this client (the offer before its Hello)."""
        processor = self.processor
        negotiated = getattr(processor, "_limits", None) if processor is not None else None
        return int(getattr(negotiated, "max_recv_buffer", CHUNK_BYTES) or CHUNK_BYTES)

    def refuse(self, code: int, text: str) -> None:
        """ERR with `code`, one (rate-limited) log line, and the connection closed."""
        self._refused = True
        self._pending.clear()
        REFUSALS.note(_host(self.peer_name), f"{ua.StatusCode(code).name}: {text}")
        if self.transport is not None:
            self.transport.write(error_message(code, text[:200]))
            self.transport.close()

    async def _process_one_msg(self, header: Any, buf: Buffer) -> bool:
        if self._refused:
            return False
        try:
            return bool(await super()._process_one_msg(header, buf))
        except Exception as exc:  # undecodable or out of sequence: never a traceback
            self.refuse(ua.StatusCodes.BadDecodingError, f"{type(exc).__name__}: {exc}")
            return False


def _host(peer: Any) -> str:
    return str(peer[0]) if isinstance(peer, tuple) and peer else str(peer)


class GuardedBinaryServer(binary_server_asyncio.BinaryServer):
    async def start(self) -> None:
        """Listen, with each connection's kernel receive buffer fixed at RECEIVE_BUFFER_BYTES
        (inherited from the listening socket): a peer can push at most that much ahead of
        what the server has read, so a refused connection's stream ends at once, and the
        kernel's memory per connection is bounded too."""
        await super().start()
        for sock in self._server.sockets if self._server is not None else ():
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)

    def _make_protocol(self) -> GuardedProtocol:
        return GuardedProtocol(
            iserver=self.iserver,
            policies=self._policies,
            clients=self.clients,
            closing_tasks=self.closing_tasks,
            limits=self.limits,
        )


def install(server: Server) -> None:
    """The guard and the limits in front of `server` (before `server.start()`). asyncua builds
    its BinaryServer inside `start()` by the name in its server module: that name is pointed at
    the guarded one (this process serves nothing else)."""
    server.limits = limits()
    server.iserver.max_connections = MAX_CONNECTIONS
    server.iserver.max_pending_activation_seconds = ACTIVATION_S
    server_module.BinaryServer = GuardedBinaryServer
