"""Laser-tracker side-car over TCP: ``tracker+tcp://host:7700``.

Line-based JSON, one request and one reply per line (LF), specified in
docs/tracker-sidecar.md so the side-car can be written against the vendor SDK. Replies echo the
request ``id``; ``ok: false`` carries ``error: {code, message}`` -> DeviceFault(code).
"""

from __future__ import annotations

import itertools
import time
from typing import Any

import numpy as np

from drivers._linesock import LineJsonSocket
from drivers.errors import DeviceConnectionError, DeviceFault, ProtocolError
from drivers.tracker import Tracker, TrackerMeasurement, TrackerStatus
from drivers.url import DeviceUrl

DEFAULT_PORT = 7700
PROTOCOL = "rvis-tracker/1"


class TcpTracker(Tracker):
    """``TcpTracker("10.0.0.9", 7700, timeout_s=30, max_rms_mm=0.05)``; open() connects."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, **kw: Any) -> None:
        kw.setdefault("name", f"tracker+tcp://{host}:{port}")
        super().__init__(**kw)
        self.host, self.port = host, int(port)
        self._sock: LineJsonSocket | None = None
        self._ids = itertools.count(1)
        self.identity = ""

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> TcpTracker:
        host, port = url.address(DEFAULT_PORT)
        return cls(host, port, **options)

    def _open(self) -> None:
        sock = LineJsonSocket(
            self.host,
            self.port,
            timeout_s=min(self.timeout_s, 5.0),
            terminator=b"\n",
            trace=self.trace,
        )
        sock.connect()
        self._sock = sock
        hello = self._request("hello", protocol=PROTOCOL)
        if hello.get("protocol") != PROTOCOL:
            raise ProtocolError(f"{self.name}: side-car speaks {hello.get('protocol')!r}")
        self.identity = f"{hello.get('tracker', '?')} s/n {hello.get('serial', '?')}"

    def _close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def describe(self) -> str:
        self._check_open()
        return self.identity

    def _targets(self) -> list[str]:
        targets = self._request("targets").get("targets")
        if not isinstance(targets, list) or not all(isinstance(t, str) for t in targets):
            raise ProtocolError(f"{self.name}: bad targets list")
        return targets

    def _status(self) -> TrackerStatus:
        r = self._request("status")
        return TrackerStatus(
            ready=bool(r.get("ready")),
            target_in_beam=bool(r.get("target_in_beam")),
            detail=str(r.get("detail", "")),
        )

    def _measure(self, target_id: str, timeout_s: float) -> TrackerMeasurement:
        r = self._request("measure", timeout_s=timeout_s, target=target_id)
        try:
            point = np.array([float(r["x_mm"]), float(r["y_mm"]), float(r["z_mm"])])
            m = TrackerMeasurement(
                str(r["target"]),
                point,
                float(r["rms_mm"]),
                str(r["time_utc"]),
                float(r["temperature_c"]),
                float(r["pressure_hpa"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"{self.name}: incomplete measurement {r}") from exc
        if m.target_id != target_id or not np.all(np.isfinite(point)):
            raise ProtocolError(f"{self.name}: measurement does not answer {target_id}: {r}")
        return m

    def _request(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """Send one request; a ``timeout_s`` field (measure) extends the wait for its reply."""
        if self._sock is None:
            raise DeviceConnectionError(f"{self.name}: not connected")
        rid = next(self._ids)
        wait = self._sock.timeout_s + float(fields.get("timeout_s", 0.0))
        self._sock.send({"id": rid, "cmd": cmd, **fields})
        deadline = time.monotonic() + wait
        while True:
            reply = self._sock.recv(max(deadline - time.monotonic(), 0.0))
            if reply.get("id") == rid:
                break
            self.log.debug("%s: skipping stale reply %s", self.name, reply)
        if reply.get("ok") is True:
            return reply
        error = reply.get("error")
        if reply.get("ok") is False and isinstance(error, dict):
            code = error.get("code", 0)
            raise DeviceFault(
                f"{self.name}: {cmd}: {error.get('message', '?')}",
                code=code if isinstance(code, int) else 0,
            )
        raise ProtocolError(f"{self.name}: malformed reply {reply}")
