"""A pytest-xdist worker in a network namespace of its own, so that the workers' loopback servers
(Aravis's GigE Vision fake camera above all: one per address, GVCP port 3956) do not meet.

`enter_own_network_namespace()` moves the calling thread (the worker's main thread, which runs
the tests; every thread and process it starts later inherits it) into a new network namespace
and brings its loopback up (127.0.0.1, as on the host). It needs CAP_SYS_ADMIN (root, as the
test command runs on a fresh Debian 12 machine and in CI); without it, or without the system
call (a container that filters it), it changes nothing and says so, and the camera tests go on
taking turns on one worker (tests/groups.py).

Only loopback exists inside: the suite talks to nothing else (REFERENCE.md: no network but the
package registries, and those are used before pytest starts).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import fcntl
import os
import socket
import struct

_CLONE_NEWNET = 0x40000000
_SIOCGIFFLAGS, _SIOCSIFFLAGS, _IFF_UP = 0x8913, 0x8914, 0x1


def _loopback_up() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        request = struct.pack("16sH14x", b"lo", 0)
        flags = struct.unpack("16sH14x", fcntl.ioctl(s, _SIOCGIFFLAGS, request))[1]
        fcntl.ioctl(s, _SIOCSIFFLAGS, struct.pack("16sH14x", b"lo", flags | _IFF_UP))


def enter_own_network_namespace() -> str | None:
    """None once this thread is in a new network namespace with its loopback up; otherwise the
    reason it is not (and nothing changed)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    if libc.unshare(_CLONE_NEWNET) != 0:
        return f"unshare(CLONE_NEWNET): {os.strerror(ctypes.get_errno())}"
    try:
        _loopback_up()
    except OSError as exc:  # a namespace without a working loopback: nothing listens there
        raise RuntimeError(f"new network namespace: loopback up: {exc}") from exc
    return None
