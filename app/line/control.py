"""The control socket: `state_dir/rvis.sock` (mode 0660), one JSON object per line each way
(docs/service-socket.md).

    -> {"id": 1, "cmd": "status"}
    <- {"id": 1, "ok": true, "state": "idle", ...}
    -> {"id": 2, "cmd": "ack", "args": {"alarm": 3}}     (or {"id": 2, "cmd": "ack", "alarm": 3})
    <- {"id": 2, "ok": false, "error": "no unacknowledged alarm 3"}
    -> {"id": 3, "cmd": "subscribe"}
    <- {"id": 3, "ok": true}   then one {"event": ..., "t": ..., ...} per line until closed

The peer's credentials (SO_PEERCRED: uid, gid; SO_PEERGROUPS: its groups; app/line/roles.py)
go with every command to the service, which decides the peer's role from them and writes the
uid to the audit log. Each connection has its own thread; the server never blocks the service
loop. A client that goes away costs only its own connection (writes use MSG_NOSIGNAL: no SIGPIPE); a
subscriber that falls `EventBus.max_queue` events behind, or whose socket accepts nothing for
`SEND_TIMEOUT_S`, is dropped with a reason (a last `{"event": "dropped", "reason": ...}` line
when it can still be sent). A request line longer than MAX_LINE gets an error and the
connection is closed (its end cannot be found without reading it all). An unexpected error in
a connection's thread goes to `on_error` (the service treats it as its own: FAULT and exit).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import queue
import socket
import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from app.line.events import EventBus
from app.line.roles import Peer, peer_credentials

MAX_LINE = 64 * 1024
REPLY_TIMEOUT_S = 60.0  # a queued command waits at most for the end of a running window
SEND_TIMEOUT_S = 10.0  # a client that accepts no byte for this long is dropped
log = logging.getLogger("rvis.line")


class Commandable(Protocol):
    bus: EventBus

    def request(
        self,
        cmd: str,
        args: dict[str, Any] | None = None,
        uid: int | None = None,
        groups: tuple[int, ...] | None = None,
    ) -> Any: ...


def _send(conn: socket.socket, obj: dict[str, Any]) -> None:
    """One line to the peer; OSError (never SIGPIPE) when it is gone or stuck."""
    conn.sendall((json.dumps(obj, default=str) + "\n").encode(), socket.MSG_NOSIGNAL)


def _send_timeout(conn: socket.socket, seconds: float) -> None:
    """Sends (only) give up after `seconds`; reads may wait for ever (idle clients are fine)."""
    whole = int(seconds)
    tv = struct.pack("ll", whole, int((seconds - whole) * 1e6))
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, tv)


class ControlServer:
    """`with ControlServer(service, path): ...` serves until closed."""

    def __init__(
        self,
        service: Commandable,
        path: str | Path,
        mode: int = 0o660,
        on_error: Callable[[BaseException], None] | None = None,
    ) -> None:
        self.service, self.path, self.mode = service, Path(path), mode
        self.on_error = on_error
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None

    def __enter__(self) -> ControlServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # a stale socket of a service that died
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o777 ^ self.mode)  # never world-accessible, not even for a moment
        try:
            sock.bind(str(self.path))
        finally:
            os.umask(old)
        os.chmod(self.path, self.mode)
        sock.listen(socket.SOMAXCONN)  # bursts of clients wait in the backlog
        sock.settimeout(0.2)
        self._sock = sock
        self._spawn(self._accept_loop)

    def _spawn(self, target: Any, *args: Any) -> None:
        t = threading.Thread(target=target, args=args, name="rvis-control", daemon=True)
        with self._lock:
            self._threads = [x for x in self._threads if x.is_alive()] + [t]
        t.start()

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            threads, conns = list(self._threads), list(self._conns)
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
        for t in threads:
            t.join()
        if self._sock is not None:
            self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def _accept_loop(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                self._conns.add(conn)
            self._spawn(self._serve, conn)

    def _serve(self, conn: socket.socket) -> None:
        try:
            peer = peer_credentials(conn)
            _send_timeout(conn, SEND_TIMEOUT_S)
            with conn, conn.makefile("rb") as lines:
                while not self._stop.is_set():
                    raw = lines.readline(MAX_LINE + 1)
                    if not raw:
                        return
                    if len(raw) > MAX_LINE and not raw.endswith(b"\n"):
                        _send(conn, {"id": None, "ok": False, "error": "request line too long"})
                        return
                    if not self._handle(conn, raw, peer):
                        return
        except OSError:
            return  # the client went away or stopped reading: only its connection ends
        except Exception as exc:
            if self.on_error is None:
                raise
            self.on_error(exc)
        finally:
            with self._lock:
                self._conns.discard(conn)

    def _handle(self, conn: socket.socket, raw: bytes, peer: Peer | None) -> bool:
        """Answer one request line; False when the connection is done."""
        try:
            req = json.loads(raw)
            if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
                raise ValueError('expected an object with a "cmd"')
            args = req.get("args")
            if args is None:  # the arguments may also stand next to "cmd"
                args = {k: v for k, v in req.items() if k not in ("id", "cmd")}
            if not isinstance(args, dict):
                raise ValueError('"args" must be an object')
        except ValueError as exc:
            _send(conn, {"id": None, "ok": False, "error": f"bad request: {exc}"})
            return True
        rid = req.get("id")
        if req["cmd"] == "subscribe":
            _send(conn, {"id": rid, "ok": True})
            self._stream(conn)
            return False
        try:
            uid, groups = (None, None) if peer is None else (peer.uid, peer.groups)
            reply = self.service.request(req["cmd"], args, uid, groups).result(REPLY_TIMEOUT_S)
        except TimeoutError:
            reply = {"ok": False, "error": "the service did not answer in time"}
        _send(conn, {"id": rid, **reply})
        return True

    def _stream(self, conn: socket.socket) -> None:
        q = self.service.bus.subscribe(drop_when_full=True)
        try:
            while not self._stop.is_set():
                if q.dropped is not None:
                    log.warning("subscriber dropped: %s", q.dropped)
                    with contextlib.suppress(OSError):
                        _send(conn, {"event": "dropped", "reason": q.dropped})
                    return
                try:
                    _send(conn, q.get(timeout=0.2))
                except queue.Empty:
                    continue
        except OSError:
            return
        finally:
            self.service.bus.unsubscribe(q)


class ControlClient:
    """A client of the control socket: `ControlClient(path).request("status")`."""

    def __init__(self, path: str | Path, timeout_s: float = REPLY_TIMEOUT_S + 5) -> None:
        self.path = Path(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(timeout_s)
        try:
            self.sock.connect(str(self.path))
        except BaseException:
            self.sock.close()
            raise
        self._lines = self.sock.makefile("rb")
        self._id = 0

    def request(self, cmd: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        self._id += 1
        _send(self.sock, {"id": self._id, "cmd": cmd, "args": args or {}})
        return self.read()

    def read(self) -> dict[str, Any]:
        line = self._lines.readline()
        if not line:
            raise ConnectionError("the service closed the connection")
        out: dict[str, Any] = json.loads(line)
        return out

    def close(self) -> None:
        self._lines.close()
        self.sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
