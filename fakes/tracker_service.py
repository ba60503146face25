"""The tracker side-car (docs/tracker-sidecar.md) on loopback, measuring a World's targets with
seeded noise. A real side-car wraps the vendor SDK behind the same protocol.

As strict as its document: a request that is not a JSON object, lacks an integer ``id`` or a
string ``cmd``, a ``hello`` without ``protocol: "rvis-tracker/1"``, or a ``measure`` without a
string ``target`` and a positive number ``timeout_s`` is answered with code 2 "bad request"
(echoing the ``id`` when there is an integer one, else ``null``); an unknown ``cmd`` with code 1.

Test controls: ``in_beam`` (False: measure answers error 11), ``fail_next(cmd, mode)`` with mode
"drop", "mute", "garble", "truncate" or an int error code.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import numpy as np

from drivers.errors import DeviceFault
from fakes._lineserver import LineServer
from fakes.devices import measure_target
from fakes.world import World

PROTOCOL = "rvis-tracker/1"
E_UNKNOWN_COMMAND, E_BAD_REQUEST, E_UNKNOWN_TARGET, E_NOT_IN_BEAM = 1, 2, 10, 11


class TrackerService(LineServer):
    """``with TrackerService(world, seed=1) as svc: TcpTracker("127.0.0.1", svc.port)``"""

    def __init__(
        self,
        world: World,
        *,
        seed: int = 0,
        noise_mm: float = 0.005,
        temperature_c: float = 20.5,
        pressure_hpa: float = 1009.0,
        **kw: Any,  # host, port: see LineServer
    ) -> None:
        super().__init__(**kw)
        self.world = world
        self.noise_mm, self.temperature_c, self.pressure_hpa = noise_mm, temperature_c, pressure_hpa
        self.rng = np.random.default_rng(seed)
        self.in_beam = True
        self.requests: list[dict[str, Any]] = []

    async def _handle(self, line: bytes, writer: asyncio.StreamWriter) -> bool:
        try:
            req = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError):
            req = None
        if not isinstance(req, dict):
            await self._send(writer, {"id": None, **_error(E_BAD_REQUEST, "not a JSON object")})
            return True
        self.requests.append(req)
        problem = _bad_request(req)
        if problem:
            rid = req.get("id") if _is_int(req.get("id")) else None
            await self._send(writer, {"id": rid, **_error(E_BAD_REQUEST, problem)})
            return True
        cmd = str(req["cmd"])
        mode = self._faults.pop(cmd, None)
        partial = b'{"id": ' + str(req.get("id")).encode()
        keep = await self._transport_fault(mode, writer, truncated=partial)
        if keep is not None:
            return keep
        if isinstance(mode, int):
            reply = {"ok": False, "error": {"code": mode, "message": "injected"}}
        else:
            reply = self._answer(cmd, req)
        await self._send(writer, {"id": req.get("id"), **reply})
        return True

    def _answer(self, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "hello":
            return {
                "ok": True,
                "protocol": PROTOCOL,
                "tracker": "rvis fake tracker",
                "serial": "FAKE-0001",
            }
        if cmd == "status":
            return {"ok": True, "ready": True, "target_in_beam": self.in_beam, "detail": ""}
        if cmd == "targets":
            return {"ok": True, "targets": self.world.target_ids()}
        if cmd == "measure":
            if not self.in_beam:
                return _error(E_NOT_IN_BEAM, "target not in beam")
            try:
                m = measure_target(
                    self.world,
                    str(req.get("target")),
                    self.rng,
                    self.noise_mm,
                    self.temperature_c,
                    self.pressure_hpa,
                )
            except DeviceFault as exc:
                return _error(E_UNKNOWN_TARGET, str(exc))
            x, y, z = (float(v) for v in m.point_mm)
            return {
                "ok": True,
                "target": m.target_id,
                "x_mm": x,
                "y_mm": y,
                "z_mm": z,
                "rms_mm": m.rms_mm,
                "time_utc": m.time_utc,
                "temperature_c": m.temperature_c,
                "pressure_hpa": m.pressure_hpa,
            }
        return _error(E_UNKNOWN_COMMAND, f"unknown command {cmd!r}")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _bad_request(req: dict[str, Any]) -> str:
    """Why the request breaks docs/tracker-sidecar.md ("" when it does not)."""
    if not _is_int(req.get("id")):
        return "every request needs an integer id"
    if not isinstance(req.get("cmd"), str):
        return "cmd must be a string"
    if req["cmd"] == "hello" and req.get("protocol") != PROTOCOL:
        return f"protocol must be {PROTOCOL!r}, got {req.get('protocol')!r}"
    if req["cmd"] == "measure":
        if not isinstance(req.get("target"), str):
            return "measure needs a string target"
        timeout = req.get("timeout_s")
        if not (isinstance(timeout, int | float) and _is_number(timeout) and timeout > 0):
            return f"measure needs a positive number timeout_s, got {timeout!r}"
    return ""


def _error(code: int, message: str) -> dict[str, Any]:
    return {"ok": False, "error": {"code": code, "message": message}}
