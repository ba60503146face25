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

The connections and sessions (app.line.opcua.admission): at most MAX_PER_PEER from one peer
address and MAX_CONNECTIONS in all, each of them; a connection or an activated session beyond a
cap takes the place of the one (pending, or activated) heard from least recently of that peer
or of the peer with the most, which gets Bad_TcpServerTooBusy after a hold (`evict`). A
connection must send its Hello within HELLO_S, have its secure channel open within CHANNEL_S and
its session activated within ACTIVATION_S of its accept (Bad_Timeout). A server that offers only
a signing-and-encrypting policy refuses an OpenSecureChannel with SecurityPolicy None
(Bad_SecurityPolicyRejected), so it never opens an unencrypted channel (asyncua 2.1.0 falls back
to its None policy), and one whose sender certificate is not trusted (Bad_SecurityChecksFailed,
OPC 10000-6 6.7.4: before decrypting anything; asyncua checks the certificate only at
CreateSession); a refused OpenSecureChannel's socket is held like an evicted one.

Every refusal is counted and logged by app.line.opcua.refusals (at most one line per peer host
per 10 s, and a few lines in all), asyncua's own records of a peer's connection too
(`QuietAsyncua`, on the server process's log handler), so a flood cannot flood the log.
`install(server)` puts the guard in front of an asyncua Server before its start.
"""

from __future__ import annotations

import asyncio
import math
import random
import socket
import struct
import time
from typing import Any

from asyncua import Server, ua
from asyncua.common.connection import TransportLimits
from asyncua.common.utils import Buffer
from asyncua.crypto.security_policies import SecurityPolicyNone
from asyncua.server import binary_server_asyncio
from asyncua.server import server as server_module
from asyncua.ua.ua_binary import header_from_binary, struct_from_binary, uatcp_to_binary

from app.line.opcua.admission import MAX_CONNECTIONS, admit, seat_session
from app.line.opcua.refusals import REFUSALS, host_of
from app.line.opcua.security import TrustValidator

HEADER = struct.Struct("<3scI")  # MessageType, ChunkType, MessageSize (OPC 10000-6, 7.1.2)
HELLO_MAX_BYTES = 8 + 5 * 4 + 4 + 4096  # header, 5 UInt32, the endpoint URL (<= 4096 bytes)
CHUNK_BYTES = 65535  # the receive and send buffers (asyncua's default)
MAX_MESSAGE_BYTES = 4 * 1024 * 1024  # a request of rvis's clients is a few kB
RECEIVE_BUFFER_BYTES = 2 * 65536  # two chunks in flight (the kernel's, per connection)
HELLO_S = 2.0  # a connection that sent no Hello is closed this long after its accept
CHANNEL_S = 5.0  # ... without an open secure channel (an RSA handshake takes milliseconds)
ACTIVATION_S = 10.0  # ... without an activated session
MAX_HELD = 4 * MAX_CONNECTIONS  # evicted connections held open (unread) for HOLD_S
HOLD_S = (1.0, 3.0)  # [s] the range an evicted connection's hold is drawn from
_HOLD = random.Random(39)  # seeded: the same draws in every run
# how far a connection got
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


HELD: set[GuardedProtocol] = set()  # evicted, not read, closed after HOLD_S


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
        self.heard_at = time.monotonic()  # its last message (admission: the least heard goes)
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.host = host_of(transport.get_extra_info("peername"))
        admit([c for c in self.clients if isinstance(c, GuardedProtocol)], self.host)
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

    def active(self) -> bool:
        """Whether its session is activated."""
        return self.progress() == ACTIVE

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
        """Its place given to a newer connection or session at once; the socket held before
        its ERR (`refuse(..., hold=True)`)."""
        self.refuse(ua.StatusCodes.BadTcpServerTooBusy, f"evicted: {why}", "evicted", hold=True)

    def _hold(self, code: int, text: str) -> None:
        """Out of the connections at once, then held, unread, for HOLD_S (drawn at random, so
        that the held do not come back all at once; MAX_HELD such at most, beyond closed at
        once), and only then ERR and closed: a peer that reopens every connection the server
        closes cannot make the evictions (or the refusals of its channels) run in a loop."""
        if self in self.clients:
            self.clients.remove(self)
        if len(HELD) >= MAX_HELD or self.transport is None:
            self._close(code, text)
            return
        self._refused = True
        self._pending.clear()
        self.transport.pause_reading()
        HELD.add(self)
        if self._deadline is not None:
            self._deadline.cancel()
        self._deadline = asyncio.get_running_loop().call_later(
            _HOLD.uniform(*HOLD_S), self._release, code, text
        )

    def _release(self, code: int, text: str) -> None:
        HELD.discard(self)
        self._close(code, text)

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
            self.heard_at = time.monotonic()
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

    def refuse(self, code: int, text: str, kind: str = "message", hold: bool = False) -> None:
        """ERR with `code`, one (rate-limited) log line, and the connection closed (after a
        hold when `hold`)."""
        REFUSALS.note(host_of(self.peer_name), f"{ua.StatusCode(code).name}: {text}", kind)
        if hold:
            self._hold(code, text)
        else:
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
        refusal = self._open_refusal(header, buf)
        if refusal is not None:  # held too: a peer reopening at once would loop on it
            self.refuse(*refusal, hold=True)
            return False
        was_active = self.active()
        try:
            going = bool(await super()._process_one_msg(header, buf))
        except Exception as exc:  # undecodable or out of sequence: never a traceback
            self.refuse(ua.StatusCodes.BadDecodingError, f"{type(exc).__name__}: {exc}")
            return False
        if not was_active and self.active() and self in self.clients:
            seat_session([c for c in self.clients if isinstance(c, GuardedProtocol)], self)
        return going

    def _open_refusal(self, header: Any, buf: Buffer) -> tuple[int, str, str] | None:
        """Why an OpenSecureChannel for a new channel is refused before asyncua reads it (None:
        it is not): SecurityPolicy None when the server does not offer it; a sender
        certificate that is not trusted, checked before anything is decrypted (OPC 10000-6
        6.7.4: Bad_SecurityChecksFailed, the reason only in the log)."""
        if header.MessageType != ua.MessageType.SecureOpen:
            return None
        if self.processor is None or self.processor._connection.is_open():
            return None  # a renewal: the channel's certificate was checked at its opening
        algorithm = struct_from_binary(ua.AsymmetricAlgorithmHeader, buf.copy(header.body_size))
        if algorithm.SecurityPolicyURI == SecurityPolicyNone.URI:
            if any(p.matches(SecurityPolicyNone.URI) for p in self.policies):
                return None
            why = "an OpenSecureChannel with SecurityPolicy None on a secure-only endpoint"
            return ua.StatusCodes.BadSecurityPolicyRejected, why, "policy"
        validator = self.iserver.certificate_validator
        if isinstance(validator, TrustValidator):
            why = validator.channel_refusal(algorithm.SenderCertificate)
            if why:
                return ua.StatusCodes.BadSecurityChecksFailed, why, "certificate"
        return None


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
    # never reached: `admit` lets in MAX_CONNECTIONS + SPARE at most
    server.iserver.max_connections = 2 * MAX_CONNECTIONS
    server.iserver.max_pending_activation_seconds = 0  # the guard's DEADLINES instead
    server_module.BinaryServer = GuardedBinaryServer
