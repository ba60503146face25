"""Tracker interop: our TCP driver against a side-car written from docs/tracker-sidecar.md alone
(no code of our peer). It makes other legal choices: CR LF line ends, extra reply fields, a
`status` detail text, replies with keys in another order."""

from __future__ import annotations

import json
import socketserver
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers import DeviceFault
from drivers.tracker_tcp import TcpTracker

NESTS = {"N1": (100.0, 200.0, 300.0), "N2": (-50.5, 0.25, 12.0)}


class DocSidecar(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.heard: list[dict[str, Any]] = []
        threading.Thread(target=self.serve_forever, args=(0.05,), daemon=True).start()

    def answer(self, req: dict[str, Any]) -> dict[str, Any]:
        self.heard.append(req)
        cmd, rid = req.get("cmd"), req.get("id")
        if cmd == "hello":
            return {"ok": True, "id": rid, "protocol": "rvis-tracker/1", "tracker": "AT960",
                    "serial": "123", "vendor_sdk": "9.1"}  # fmt: skip
        if cmd == "status":
            return {"id": rid, "ok": True, "ready": True, "target_in_beam": False,
                    "detail": "beam parked"}  # fmt: skip
        if cmd == "targets":
            return {"id": rid, "ok": True, "targets": sorted(NESTS)}
        if cmd == "measure" and req.get("target") in NESTS:
            x, y, z = NESTS[req["target"]]
            return {"id": rid, "ok": True, "target": req["target"], "x_mm": x, "y_mm": y,
                    "z_mm": z, "rms_mm": 0.003, "time_utc": "2026-01-05T10:31:07+00:00",
                    "temperature_c": 21.0, "pressure_hpa": 1002.0, "samples": 400}  # fmt: skip
        if cmd == "measure":
            return {"id": rid, "ok": False, "error": {"code": 10, "message": "no such nest"}}
        return {"id": rid, "ok": False, "error": {"code": 1, "message": "unknown command"}}


class _Handler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        server = self.server
        assert isinstance(server, DocSidecar)
        for line in self.rfile:
            reply = server.answer(json.loads(line))
            self.wfile.write(json.dumps(reply).encode() + b"\r\n")


@pytest.fixture
def sidecar() -> Iterator[DocSidecar]:
    server = DocSidecar()
    yield server
    server.shutdown()
    server.server_close()


def test_our_driver_against_a_sidecar_from_the_document(sidecar: DocSidecar) -> None:
    with TcpTracker("127.0.0.1", sidecar.server_address[1], timeout_s=1.0) as tracker:
        assert tracker.describe() == "AT960 s/n 123"
        assert tracker.targets() == ["N1", "N2"]
        status = tracker.status()
        assert status.ready and not status.target_in_beam and status.detail == "beam parked"
        m = tracker.measure("N2", timeout_s=5.0)
        np.testing.assert_allclose(m.point_mm, NESTS["N2"])
        assert (m.rms_mm, m.temperature_c, m.pressure_hpa) == (0.003, 21.0, 1002.0)
        with pytest.raises(DeviceFault) as info:
            tracker.measure("N9")
        assert info.value.code == 10
    assert sidecar.heard[0] == {"id": sidecar.heard[0]["id"], "cmd": "hello",
                                "protocol": "rvis-tracker/1"}  # fmt: skip
    assert all(isinstance(r["id"], int) for r in sidecar.heard)
