"""The OPC UA endpoint's rules, without importing asyncua (the cell file is checked with them).

Anonymous, unencrypted access is for the machine itself: an endpoint that listens beyond the
loopback interface must offer only a signing-and-encrypting security policy (DESIGN.md
section 8). `endpoint_problem` says why an endpoint cannot be used ("" when it can);
`cannot_listen` why the server could not listen at one (the one mapping of listen errors: the
server's own listen fails, nothing probes the port before it).
"""

from __future__ import annotations

import errno
import ipaddress
import socket
from urllib.parse import urlsplit

#: the security policies the server offers (always in SignAndEncrypt mode); "none": no security
SECURITY_POLICIES = ("none", "Basic256Sha256", "Aes128Sha256RsaOaep", "Aes256Sha256RsaPss")
SCHEME = "opc.tcp"
DEFAULT_PORT = 4840
LOOPBACK_NAMES = ("localhost", "localhost.localdomain", "ip6-localhost")
FIELD = "[opcua] endpoint"  # the setting an error about the endpoint names


def split_endpoint(endpoint: str) -> tuple[str, int]:
    """(host, port) of an `opc.tcp://host:port/path` URL; ValueError with the reason."""
    parts = urlsplit(endpoint)
    if parts.scheme != SCHEME:
        raise ValueError(f"expected {SCHEME}://host:port/path, got {endpoint!r}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError as exc:  # a port that is not a number or out of range
        raise ValueError(f"bad port in {endpoint!r}: {exc}") from None
    if not host:
        raise ValueError(f"no host in {endpoint!r}")
    return host, DEFAULT_PORT if port is None else port


def is_loopback(host: str) -> bool:
    """Whether `host` names the loopback interface only (0.0.0.0 and :: are every interface)."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it resolves to a real interface


def endpoint_problem(endpoint: str, security_policy: str) -> str:
    """Why the server cannot listen at `endpoint` with `security_policy` ("" when it can)."""
    try:
        host, _port = split_endpoint(endpoint)
    except ValueError as exc:
        return str(exc)
    if security_policy not in SECURITY_POLICIES:
        return (
            f"unknown security policy {security_policy!r} (known: {', '.join(SECURITY_POLICIES)})"
        )
    if security_policy == "none" and not is_loopback(host):
        return (
            f"{host} is not a loopback address: beyond loopback the server needs a signing-and-"
            'encrypting security_policy ("Basic256Sha256" or newer) and certificates'
        )
    return ""


def cannot_listen(endpoint: str, why: OSError | str) -> str:
    """The one line that says why the server cannot listen at `endpoint`: a listen's OSError
    by its errno in words (the port taken, a privileged port, a host that is not this
    machine's, a name that does not resolve), another one by its text, or the reason given."""
    try:
        host, port = split_endpoint(endpoint)
    except ValueError:
        host, port = endpoint, DEFAULT_PORT
    if isinstance(why, str):
        reason = why
    elif isinstance(why, socket.gaierror):
        reason = f"the host name {host} does not resolve ({why.strerror or why})"
    elif why.errno == errno.EADDRINUSE:
        reason = f"port {port} is in use by another program"
    elif why.errno == errno.EACCES:
        reason = f"permission denied for port {port} (ports below 1024 need privileges)"
    elif why.errno == errno.EADDRNOTAVAIL:
        reason = f"{host} is not an address of this machine"
    else:
        reason = why.strerror or str(why)
    return " ".join(f"cannot listen at {endpoint}: {reason}".split())
