"""A blocking TCP connection exchanging one JSON object per line (RMI, tracker side-car).

Maps every socket and JSON error to the device error tree at this boundary; with a trace
channel, every line sent and received (and every error) goes to the wire trace.
"""

from __future__ import annotations

import json
import socket
import time
from typing import Any

from drivers.errors import DeviceConnectionError, DeviceError, DeviceTimeout, ProtocolError
from drivers.trace import TraceChannel

_MAX_LINE = 1 << 20


class LineJsonSocket:
    """One TCP connection; ``send`` writes a JSON object + terminator, ``recv`` reads one."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        timeout_s: float,
        terminator: bytes,
        trace: TraceChannel | None = None,
    ) -> None:
        self.host, self.port, self.timeout_s, self.terminator = host, port, timeout_s, terminator
        self.trace = trace
        self._sock: socket.socket | None = None
        self._buf = b""

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    def connect(self) -> None:
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except TimeoutError as exc:
            raise DeviceTimeout(f"{self.where}: connect timed out") from exc
        except OSError as exc:
            raise DeviceConnectionError(f"{self.where}: cannot connect: {exc}") from exc
        # small request/reply lines: without this, Nagle holds a second line (an abort sent
        # while a motion's reply is pending) until the peer's delayed ACK, tens of ms
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buf = b""

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def send(self, message: dict[str, Any]) -> None:
        sock = self._require()
        data = json.dumps(message, separators=(",", ":")).encode() + self.terminator
        if self.trace is not None:
            self.trace.tx(f"{self.where} {data[: -len(self.terminator)].decode()}")
        try:
            sock.settimeout(self.timeout_s)
            sock.sendall(data)
        except TimeoutError as exc:
            raise self._noted(DeviceTimeout(f"{self.where}: send timed out")) from exc
        except OSError as exc:
            raise self._noted(DeviceConnectionError(f"{self.where}: send failed: {exc}")) from exc

    def recv(self, timeout_s: float | None = None) -> dict[str, Any]:
        """Read one JSON object; DeviceTimeout if no full line arrives within ``timeout_s``."""
        try:
            line = self._read_line(self.timeout_s if timeout_s is None else timeout_s)
        except DeviceError as exc:
            self._noted(exc)
            raise
        if self.trace is not None:
            self.trace.rx(f"{self.where} {line.decode(errors='replace')}")
        try:
            message = json.loads(line)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ProtocolError(f"{self.where}: malformed reply {line[:80]!r}") from exc
        if not isinstance(message, dict):
            raise ProtocolError(f"{self.where}: reply is not a JSON object: {line[:80]!r}")
        return message

    def _noted(self, exc: DeviceError) -> DeviceError:
        """``exc``, written to the trace first (when on)."""
        if self.trace is not None:
            self.trace.note(f"{self.where} {type(exc).__name__}: {exc}")
        return exc

    def _require(self) -> socket.socket:
        if self._sock is None:
            raise DeviceConnectionError(f"{self.where}: not connected")
        return self._sock

    def _read_line(self, timeout_s: float) -> bytes:
        sock = self._require()
        deadline = time.monotonic() + timeout_s
        while (end := self._buf.find(b"\n")) < 0:
            if len(self._buf) > _MAX_LINE:
                raise ProtocolError(f"{self.where}: reply line too long")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self.where}: no reply within {timeout_s:g} s")
            try:
                sock.settimeout(remaining)
                chunk = sock.recv(65536)
            except TimeoutError as exc:
                raise DeviceTimeout(f"{self.where}: no reply within {timeout_s:g} s") from exc
            except OSError as exc:
                raise DeviceConnectionError(f"{self.where}: receive failed: {exc}") from exc
            if not chunk:
                self.close()
                if self._buf.strip():
                    raise ProtocolError(f"{self.where}: truncated reply {self._buf[:80]!r}")
                raise DeviceConnectionError(f"{self.where}: peer closed the connection")
            self._buf += chunk
        line, self._buf = self._buf[:end], self._buf[end + 1 :]
        return line.strip()
