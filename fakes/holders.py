"""Who holds a lock file or a UDP port on this machine, from /proc (Linux), in words for a
person: `pid 1234 (rvis devices sim --dir sim)`. For the simulated devices that must wait for
another process's (fakes/gv_camera.py: the GigE fake camera's address, one per address).

    process_text(pid)             "pid 1234 (python -m app devices sim --dir sim)"
    flock_holder(fd)              the pid holding an flock on the open file `fd` (None: none)
    udp_port_holder(address, n)   the pid whose socket is bound to UDP `address`:`n` (or to
                                  any address on that port; None: none seen)

Best effort: a process this user may not look at (another user's /proc/PID/fd) is not found,
and None says so; nothing here raises for what /proc does not show.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
from pathlib import Path

PROC = Path("/proc")
#: the longest command line quoted (a person's terminal line)
CMDLINE_CHARS = 120


def process_text(pid: int | str) -> str:
    """`pid N (its command line)`, or `pid N` when /proc does not show its command line."""
    try:
        raw = (PROC / str(pid) / "cmdline").read_bytes()
    except OSError:
        return f"pid {pid}"
    words = [w.decode(errors="replace") for w in raw.split(b"\0") if w]
    if not words:
        return f"pid {pid}"
    text = " ".join(" ".join(words).split())  # one line, whatever the arguments hold
    if len(text) > CMDLINE_CHARS:
        text = text[: CMDLINE_CHARS - 3] + "..."
    return f"pid {pid} ({text})"


def flock_holder(fd: int) -> int | None:
    """The pid holding an flock on the file open as `fd` (/proc/locks), if another holds one."""
    st = os.fstat(fd)
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = (PROC / "locks").read_text(encoding="ascii", errors="replace").splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 1234 fd:00:260072 0 EOF" ("->" marks a waiter)
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[2] != "->" and fields[5] == key:
            with contextlib.suppress(ValueError):
                return int(fields[4])
    return None


def udp_port_holder(address: str, port: int) -> int | None:
    """The pid of a process with a UDP socket bound to `address`:`port` or to the wildcard
    address on that port (/proc/net/udp, then the sockets among /proc/*/fd)."""
    try:
        wanted = {_hex_address(address, port), _hex_address("0.0.0.0", port)}
        table = (PROC / "net" / "udp").read_text(encoding="ascii").splitlines()[1:]
    except (OSError, ValueError):
        return None
    inodes = {f"socket:[{f[9]}]" for f in (line.split() for line in table) if f[1] in wanted}
    if not inodes:
        return None
    for entry in PROC.iterdir():
        if not entry.name.isdigit() or entry.name == str(os.getpid()):
            continue
        with contextlib.suppress(OSError):
            for fd in (entry / "fd").iterdir():
                with contextlib.suppress(OSError):
                    if os.readlink(fd) in inodes:
                        return int(entry.name)
    return None


def _hex_address(address: str, port: int) -> str:
    """`address`:`port` as /proc/net/udp writes it ("0100007F:0F74": the address in host
    byte order)."""
    packed = socket.inet_aton(address)
    return f"{struct.unpack('=I', packed)[0]:08X}:{port:04X}"
