"""Peers of the OPC UA port, for the tests and the hostile-peer bench (bench/opcua_hostile.py):
raw messages, a peer that holds connections (raw, or asyncua sessions created or activated) and
reopens each one the server closes, and a well-behaved asyncua client that connects, creates a
session and reads.

Every loop here is bounded in time and in count and talks only to the address it is given.
"""

from __future__ import annotations

import asyncio
import contextlib
import selectors
import socket
import struct
import threading
from collections.abc import Sequence
from pathlib import Path

from asyncua import Client, ua
from asyncua.client.ua_client import UaClientState
from asyncua.common.connection import SecureConnection, TransportLimits
from asyncua.common.utils import create_nonce
from asyncua.crypto import security_policies, uacrypto
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.ua.ua_binary import struct_to_binary
from cryptography.x509.oid import ExtendedKeyUsageOID

from app.line.opcua.space import NS_MACHINERY, NS_RVIS

MAX_OPENS = 500_000  # a holder's connections in all, at most


def split_url(url: str) -> tuple[str, int]:
    host, port = url.split("//")[1].split("/")[0].rsplit(":", 1)
    return host.strip("[]"), int(port)


def hello_message(url: str, size_claimed: int | None = None) -> bytes:
    """A Hello; with `size_claimed`, its header claims that size (the rest never comes)."""
    endpoint = url.encode()
    body = struct.pack("<IIIIIi", 0, 65535, 65535, 0, 0, len(endpoint)) + endpoint
    size = 8 + len(body) if size_claimed is None else size_claimed
    return struct.pack("<3scI", b"HEL", b"F", size) + body


def open_channel_message(policy: security_policies.SecurityPolicy | None = None) -> bytes:
    """An OpenSecureChannel request (SecurityPolicy None, as a discovery client sends, unless
    `policy`: signed and encrypted by it, its certificate the sender's). The same bytes open a
    channel on every connection (a server keeps no record of the nonces it was sent)."""
    policy = policy or security_policies.SecurityPolicyNone()
    connection = SecureConnection(policy, TransportLimits())
    request = ua.OpenSecureChannelRequest()
    request.Parameters.SecurityMode = policy.Mode
    request.Parameters.RequestedLifetime = 3_600_000
    request.Parameters.ClientNonce = create_nonce(policy.secure_channel_nonce_length)
    data: bytes = connection.message_to_binary(
        struct_to_binary(request), message_type=ua.MessageType.SecureOpen, request_id=1
    )
    return data


def error_code(answer: bytes) -> int:
    """The status code of an ERR message."""
    assert answer[:4] == b"ERRF", answer[:16]
    code: int = struct.unpack_from("<I", answer, 8)[0]
    return code


def read_until_closed(s: socket.socket, timeout_s: float = 10.0) -> bytes:
    """What the server sends until it closes the connection (bounded by `timeout_s`)."""
    s.settimeout(timeout_s)
    answer = b""
    with contextlib.suppress(OSError):  # a reset after the ERR, or the timeout
        while chunk := s.recv(65536):
            answer += chunk
    return answer


async def basic256sha256(
    cert: Path, key: Path, server_cert: Path
) -> security_policies.SecurityPolicy:
    """The client side of Basic256Sha256 Sign & Encrypt with this certificate and key."""
    return security_policies.SecurityPolicyBasic256Sha256(
        await uacrypto.load_certificate(server_cert),
        await uacrypto.load_certificate(cert),
        await uacrypto.load_private_key(key),
        ua.MessageSecurityMode.SignAndEncrypt,
    )


class Holder:
    """A hostile peer: holds `count` connections to `url` (spread over the `sources` addresses,
    `send` sent on each: nothing, a Hello, a Hello and an OpenSecureChannel; nothing after) and
    reopens each one the server closes, at once, until `stop()` (at most MAX_OPENS
    connections). `evicted` is set at the first connection the server closes."""

    def __init__(
        self, url: str, count: int, *, sources: Sequence[str] = ("127.0.0.1",), send: bytes = b""
    ) -> None:
        self.address = split_url(url)
        self.url, self.count, self.sources, self.send = url, count, tuple(sources), send
        self.opens = 0
        self.closed_by_server = 0
        self.connect_failures = 0
        self.evicted = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hostile-holder", daemon=True)

    def __enter__(self) -> Holder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(30)

    def _open(self, selector: selectors.BaseSelector, k: int) -> None:
        if self.opens >= MAX_OPENS or self._stop.is_set():
            return
        source = self.sources[k % len(self.sources)]
        try:
            s = socket.create_connection(self.address, timeout=2, source_address=(source, 0))
        except OSError:
            self.connect_failures += 1
            return
        self.opens += 1
        with contextlib.suppress(OSError):  # closed by the server meanwhile: seen below
            s.sendall(self.send)
        s.setblocking(False)
        selector.register(s, selectors.EVENT_READ, k)

    def _run(self) -> None:
        with selectors.DefaultSelector() as selector:
            for k in range(self.count):
                self._open(selector, k)
            while not self._stop.is_set() and selector.get_map():
                for key, _ in selector.select(timeout=0.1):
                    s = key.fileobj
                    assert isinstance(s, socket.socket)
                    try:
                        data = s.recv(65536)
                    except BlockingIOError:
                        continue
                    except OSError:
                        data = b""
                    if data:
                        continue  # the Acknowledge, or an ERR before the close
                    selector.unregister(s)
                    s.close()
                    self.closed_by_server += 1
                    self.evicted.set()
                    self._open(selector, key.data)
            for key in list(selector.get_map().values()):
                with contextlib.suppress(OSError):
                    key.fileobj.close()  # type: ignore[union-attr]


class SessionHolder:
    """A hostile peer of asyncua sessions: holds `count` sessions to `url` (spread over the
    `sources` addresses), each created and, when `activate`, activated (anonymous), then idle;
    reopens each one the server closes until `stop()` (at most MAX_OPENS). `full` is set once
    `count` are held at the same time, `evicted` at the first one the server closes."""

    def __init__(
        self,
        url: str,
        count: int,
        *,
        sources: Sequence[str] = ("127.0.0.1",),
        activate: bool = True,
        timeout_s: float = 10.0,
    ) -> None:
        self.url, self.count, self.sources = url, count, tuple(sources)
        self.activate, self.timeout_s = activate, timeout_s
        self.opens = 0
        self.held = 0
        self.closed_by_server = 0
        self.failures = 0
        self.full = threading.Event()
        self.evicted = threading.Event()
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = threading.Thread(target=asyncio.run, args=(self._run(),), daemon=True)

    def __enter__(self) -> SessionHolder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            loop.call_soon_threadsafe(stop.set)
        self._thread.join(30)

    async def _run(self) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        tasks = [asyncio.create_task(self._hold(k)) for k in range(self.count)]
        await self._stop.wait()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        # the transports' closing callbacks run before the loop ends: nothing to wait on
        await asyncio.sleep(0.1)  # sleep-ok

    async def _hold(self, k: int) -> None:
        """One session after another from `sources[k]`, each held until the server closes it."""
        assert self._stop is not None
        while not self._stop.is_set() and self.opens < MAX_OPENS:
            self.opens += 1
            client = Client(self.url, timeout=self.timeout_s)
            closed = asyncio.Event()
            try:
                await self._open(client, self.sources[k % len(self.sources)], closed)
                self.held += 1
                if self.held >= self.count:
                    self.full.set()
                try:
                    await closed.wait()
                finally:
                    self.held -= 1
                self.closed_by_server += 1
                self.evicted.set()
            except (OSError, TimeoutError, ua.UaError):
                self.failures += 1
                await asyncio.sleep(0.1)  # sleep-ok: a refused peer retries, not in a tight loop
            finally:
                client.uaclient.disconnect_socket()

    async def _open(self, client: Client, source: str, closed: asyncio.Event) -> None:
        uaclient = client.uaclient
        host, port = split_url(self.url)
        uaclient._set_state(UaClientState.CONNECTING)  # asyncua's connect_socket, bound here
        await asyncio.wait_for(
            asyncio.get_running_loop().create_connection(
                uaclient._make_protocol, host, port, local_addr=(source, 0)
            ),
            self.timeout_s,
        )
        uaclient._set_state(UaClientState.SOCKET_OPEN)
        assert uaclient.protocol is not None
        uaclient.protocol.on_connection_lost = lambda _exc: closed.set()
        await client.send_hello()
        await client.open_secure_channel()
        await client.create_session()
        if self.activate:
            await client.activate_session()


async def client_certificate(folder: Path, name: str) -> tuple[Path, Path]:
    """A client's self-signed application certificate and key in `folder` (NAME.der,
    NAME.pem; its application URI urn:test:NAME, as `read_state` names it)."""
    cert, key = folder / f"{name}.der", folder / f"{name}.pem"
    await setup_self_signed_certificate(
        key, cert, f"urn:test:{name}", "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {}
    )
    return cert, key


async def read_state(
    url: str,
    *,
    cert: Path | None = None,
    key: Path | None = None,
    server_cert: Path | None = None,
    timeout_s: float = 10.0,
) -> str:
    """A well-behaved client: connect (SignAndEncrypt with Basic256Sha256 when `cert`), create
    and activate a session, read the machine's ServiceState, disconnect."""
    client = Client(url, timeout=timeout_s)
    if cert is not None and key is not None:
        client.application_uri = f"urn:test:{cert.stem}"
        await client.set_security(
            security_policies.SecurityPolicyBasic256Sha256,
            str(cert),
            str(key),
            server_certificate=None if server_cert is None else str(server_cert),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
    async with asyncio.timeout(3 * timeout_s), client:
        ns = await client.get_namespace_index(NS_RVIS)
        ns_m = await client.get_namespace_index(NS_MACHINERY)
        machines = await client.nodes.objects.get_child(f"{ns_m}:Machines")
        mine = [n for n in await machines.get_children() if n.nodeid.NamespaceIndex == ns]
        node = await mine[0].get_child(f"{ns}:ServiceState")
        value: str = await node.read_value()
        return value
