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
the kernel, and the messages it assembles are bounded by `limits()`.

The connections (`admit`): at most MAX_PER_PEER from one peer address and MAX_CONNECTIONS in
all. A connection that would pass either cap takes the place of the least advanced one without
an activated session (of that peer, or of the whole server: no Hello yet < Hello < secure
channel < session not activated, a connection in its first HELLO_GRACE_S counted as one whose
Hello came; then the peer with the most connections, then the oldest), which gets
Bad_TcpServerTooBusy (after a hold: `evict`); the new one is refused only when every one has an
activated session. So a peer that holds sockets and reopens each one the server closes keeps
evicting its own idle sockets, never a client that is further on. A connection must send its
Hello within HELLO_S, have its secure channel open within CHANNEL_S and its session activated
within ACTIVATION_S of its accept (Bad_Timeout). A server that offers only a signing-and-
encrypting policy refuses an OpenSecureChannel with SecurityPolicy None
(Bad_SecurityPolicyRejected), so it never opens an unencrypted channel (asyncua 2.1.0 falls
back to its None policy).

Every refusal is counted (`REFUSALS.counts`) and logged at most once per LOG_EVERY_S per peer
host (with the number refused meanwhile), asyncua's own records of a peer's connection too
(`QuietAsyncua`, on the server process's log handler), so a flood cannot flood the log.
`install(server)` puts the guard in front of an asyncua Server before its start.
"""

from __future__ import annotations

import asyncio
import logging
import math
import random
import socket
import struct
import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

from asyncua import Server, ua
from asyncua.common.connection import TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto.security_policies import SecurityPolicyNone
from asyncua.server import binary_server_asyncio
from asyncua.server import server as server_module
from asyncua.ua.ua_binary import header_from_binary, struct_from_binary, uatcp_to_binary

log = logging.getLogger("rvis.line.opcua")

HEADER = struct.Struct("<3scI")  # MessageType, ChunkType, MessageSize (OPC 10000-6, 7.1.2)
HELLO_MAX_BYTES = 8 + 5 * 4 + 4 + 4096  # header, 5 UInt32, the endpoint URL (<= 4096 bytes)
CHUNK_BYTES = 65535  # the receive and send buffers (asyncua's default)
MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # a request of rvis's clients is a few kB
RECEIVE_BUFFER_BYTES = 2 * 65536  # two chunks in flight (the kernel's, per connection)
MAX_CONNECTIONS = 64  # a cell's clients: SCADA, MES, a historian, engineering tools
MAX_PER_PEER = 16  # from one address (every client on the cell's computer is one: 127.0.0.1)
HELLO_S = 2.0  # a connection that sent no Hello is closed this long after its accept
HELLO_GRACE_S = 0.5  # ... and is evicted as one without a Hello only after this
CHANNEL_S = 5.0  # ... without an open secure channel (an RSA handshake takes milliseconds)
ACTIVATION_S = 10.0  # ... without an activated session
MAX_HELD = 4 * MAX_CONNECTIONS  # evicted connections held open (unread) for HOLD_S
HOLD_S = (1.0, 3.0)  # [s] the range an evicted connection's hold is drawn from
_HOLD = random.Random(39)  # seeded: the same draws in every run
LOG_EVERY_S = 10.0
# how far a connection got (the least advanced is evicted first)
CONNECTED, HELLO, CHANNEL, SESSION, ACTIVE = range(5)
DEADLINES = ((HELLO_S, HELLO, "no Hello"), (CHANNEL_S, CHANNEL, "no secure channel"),
             (ACTIVATION_S, ACTIVE, "no activated session"))  # fmt: skip
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


class Throttle:
    """At most one line per key per LOG_EVERY_S: `due(key)` is None while it is quiet, else the
    number of lines held back since the last one."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, int]] = {}

    def due(self, key: str) -> int | None:
        now = time.monotonic()
        last, quiet = self._last.get(key, (-math.inf, 0))
        if now - last < LOG_EVERY_S:
            self._last[key] = (last, quiet + 1)
            return None
        self._last[key] = (now, 0)
        if len(self._last) > 1024:  # many keys: forget the quiet ones
            self._last = {k: v for k, v in self._last.items() if now - v[0] < LOG_EVERY_S}
        return quiet


class RefusalLog:
    """Every refusal counted by its status (`counts`); one log line per peer host per
    LOG_EVERY_S (with how many were refused meanwhile)."""

    def __init__(self) -> None:
        self._throttle = Throttle()
        self.counts: Counter[str] = Counter()

    def note(self, host: str, text: str, kind: str = "refused") -> None:
        self.counts[kind] += 1
        quiet = self._throttle.due(host)
        if quiet is None:
            return
        more = f" ({quiet} more refused from {host} in the last {LOG_EVERY_S:g} s)" if quiet else ""
        log.warning("OPC UA connection from %s refused: %s%s", host, text, more)


REFUSALS = RefusalLog()
HELD: set[GuardedProtocol] = set()  # evicted, not read, closed after HOLD_S


class QuietAsyncua(logging.Filter):
    """asyncua's records in the server process, rate-limited like the guard's: one about a
    peer's connection (its first argument the peer's address, as in "Refusing connection from
    %s: at max_connections=%s") goes to REFUSALS; any other at most once per message per
    LOG_EVERY_S, with the number held back."""

    def __init__(self) -> None:
        super().__init__()
        self._throttle = Throttle()

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.name.startswith("asyncua"):
            return True
        args = record.args if isinstance(record.args, tuple) else ()
        if args and isinstance(args[0], tuple):
            REFUSALS.note(_host(args[0]), f"asyncua: {record.getMessage()}", "asyncua")
            return False
        quiet = self._throttle.due(f"{record.name}:{record.msg}")
        if quiet is None:
            return False
        if quiet:
            record.msg = (
                f"{record.getMessage()} ({quiet} more like it in the last {LOG_EVERY_S:g} s)"
            )
            record.args = None
        return True


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
        self.host = ""
        self.accepted_at = time.monotonic()
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.host = _host(transport.get_extra_info("peername"))
        clients = [c for c in self.clients if isinstance(c, GuardedProtocol)]
        full = admit(clients, self.host)
        if full:
            self._refused = True
            REFUSALS.note(self.host, f"BadTcpServerTooBusy: {full}", "too busy")
            assert isinstance(transport, asyncio.WriteTransport)
            transport.write(error_message(ua.StatusCodes.BadTcpServerTooBusy, full[:200]))
            transport.close()
            return
        super().connection_made(transport)
        self._deadline = asyncio.get_running_loop().call_later(HELLO_S, self._check, 0)

    def connection_lost(self, ex: BaseException | None) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        HELD.discard(self)
        super().connection_lost(ex)

    def progress(self) -> int:
        """How far this connection got: CONNECTED, HELLO, CHANNEL, SESSION or ACTIVE."""
        processor = self.processor
        if not self._hello or processor is None:
            return CONNECTED
        if not processor._connection.is_open():
            return HELLO
        session = processor.session
        if session is None:
            return CHANNEL
        return ACTIVE if session.is_activated() else SESSION

    def rank(self, now: float) -> int:
        """`progress()` as eviction sees it: in its first HELLO_GRACE_S a connection counts as
        one whose Hello came (it may be on its way: a client's Hello follows its connect at
        once, but the server reads it only after the accepts queued before it)."""
        progress = self.progress()
        young = now - self.accepted_at < HELLO_GRACE_S
        return HELLO if progress == CONNECTED and young else progress

    def _check(self, stage: int) -> None:
        """Closed when it did not get as far as DEADLINES[stage] asks by then."""
        after_s, needed, what = DEADLINES[stage]
        if self._refused or self.transport is None:
            return
        if self.progress() < needed:
            self.refuse(ua.StatusCodes.BadTimeout, f"{what} within {after_s:g} s", "deadline")
        elif stage + 1 < len(DEADLINES):
            wait_s = DEADLINES[stage + 1][0] - after_s
            self._deadline = asyncio.get_running_loop().call_later(wait_s, self._check, stage + 1)

    def evict(self, why: str) -> None:
        """Its slot given to a new connection at once. The socket itself is held, unread, for
        HOLD_S (drawn at random, so that the evicted do not come back all at once; MAX_HELD such
        at most, beyond closed at once), and only then gets ERR and is closed: a peer that
        reopens every connection the server closes cannot make the evictions run in a loop."""
        if self in self.clients:
            self.clients.remove(self)
        if len(HELD) >= MAX_HELD or self.transport is None:
            self.refuse(ua.StatusCodes.BadTcpServerTooBusy, f"evicted: {why}", "evicted")
            return
        REFUSALS.note(self.host, f"BadTcpServerTooBusy: evicted: {why}", "evicted")
        self._refused = True
        self._pending.clear()
        self.transport.pause_reading()
        HELD.add(self)
        if self._deadline is not None:
            self._deadline.cancel()
        self._deadline = asyncio.get_running_loop().call_later(
            _HOLD.uniform(*HOLD_S), self._release
        )

    def _release(self) -> None:
        HELD.discard(self)
        self._close(ua.StatusCodes.BadTcpServerTooBusy, "evicted for a new connection")

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

    def refuse(self, code: int, text: str, kind: str = "message") -> None:
        """ERR with `code`, one (rate-limited) log line, and the connection closed."""
        REFUSALS.note(_host(self.peer_name), f"{ua.StatusCode(code).name}: {text}", kind)
        self._close(code, text)

    def _close(self, code: int, text: str) -> None:
        self._refused = True
        self._pending.clear()
        if self.transport is not None:
            self.transport.write(error_message(code, text[:200]))
            self.transport.close()

    async def _process_one_msg(self, header: Any, buf: Buffer) -> bool:
        if self._refused:
            return False
        if header.MessageType == ua.MessageType.SecureOpen and self._unsecured_open(header, buf):
            self.refuse(
                ua.StatusCodes.BadSecurityPolicyRejected,
                "an OpenSecureChannel with SecurityPolicy None on a secure-only endpoint",
                "policy",
            )
            return False
        try:
            return bool(await super()._process_one_msg(header, buf))
        except Exception as exc:  # undecodable or out of sequence: never a traceback
            self.refuse(ua.StatusCodes.BadDecodingError, f"{type(exc).__name__}: {exc}")
            return False

    def _unsecured_open(self, header: Any, buf: Buffer) -> bool:
        """Whether this OpenSecureChannel asks for SecurityPolicy None (a new channel) when
        the server does not offer it."""
        if self.processor is None or self.processor._connection.is_open():
            return False
        if any(p.matches(SecurityPolicyNone.URI) for p in self.policies):
            return False
        algorithm = struct_from_binary(ua.AsymmetricAlgorithmHeader, buf.copy(header.body_size))
        return bool(algorithm.SecurityPolicyURI == SecurityPolicyNone.URI)


def admit(clients: Sequence[GuardedProtocol], host: str) -> str:
    """Room for a new connection from `host` among `clients` ("": admitted, the least advanced
    connection without an activated session evicted when a cap is reached; else why not)."""
    mine = [c for c in clients if c.host == host]
    if len(mine) >= MAX_PER_PEER:
        pool, why = mine, f"{host} holds {len(mine)} connections (at most {MAX_PER_PEER} a peer)"
    elif len(clients) >= MAX_CONNECTIONS:
        pool, why = (
            list(clients),
            f"the server holds {len(clients)} connections (at most {MAX_CONNECTIONS})",
        )
    else:
        return ""
    idle = [c for c in pool if c.progress() < ACTIVE]
    if not idle:
        return f"{why}, each with an activated session"
    per_host = Counter(c.host for c in clients)
    now = time.monotonic()
    min(idle, key=lambda c: (c.rank(now), -per_host[c.host], c.accepted_at)).evict(why)
    return ""


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
    server.iserver.max_connections = MAX_CONNECTIONS  # never reached: `admit` makes room
    server.iserver.max_pending_activation_seconds = 0  # the guard's DEADLINES instead
    server_module.BinaryServer = GuardedBinaryServer
