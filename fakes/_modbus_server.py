"""A pymodbus 3.16 TCP server on loopback with a block of holding registers and a hook that runs
the device logic on every access (the way a PLC or TP program scans its registers).

pymodbus calls the SimDevice ``action`` before it applies a write, with the live register list;
subclasses implement ``scan(now, regs, written)``: ``regs`` is that list (address 0 = index 0),
``written`` maps the addresses of a write request to their new values (empty for a read). State
therefore advances lazily, driven by the client's polling and the clock (``clock=``, real time by
default): no background task. A single-register write (FC6) is answered with the request's
echo, as Modbus requires: pymodbus reads the register back to build that reply, and no scan runs
between the write and that read.

As strict as the device it plays, when told: ``unit`` (the Modbus unit id it answers; a request
to another unit gets exception 0x0B "gateway target device failed to respond", as pymodbus's
server and a gateway answer; None: any unit) and ``function_codes`` (the ones its register map
supports; any other gets exception 0x01 "illegal function"; None: every one pymodbus serves).

Fault injection (one-shot): ``fail_next(mode)`` with "exception" (Modbus exception 4, device
failure), "drop" (close every client connection), "mute" (hold the reply past any timeout) or
"garble" (send a frame with a wrong protocol id, then hold the reply: the client's stream is out
of step, as after a corrupted or truncated frame), optionally only for one function code.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterable
from typing import Self

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from fakes._loop import LoopThread
from fakes.clock import Clock, RealClock

# An MBAP header with protocol id 0x0B0B instead of 0, and a stray register: not a reply.
_GARBLED = bytes([0x00, 0x01, 0x0B, 0x0B, 0x00, 0x05, 0x01, 0x03, 0x02, 0xFF])


class RegisterServer:
    """Base of the Modbus peers; subclasses implement ``scan``."""

    def __init__(
        self,
        *,
        size: int,
        host: str = "127.0.0.1",
        port: int = 0,
        clock: Clock | None = None,
        unit: int | None = None,
        function_codes: Iterable[int] | None = None,
    ) -> None:
        self.host, self._want_port, self.size = host, port, size
        if unit is not None and not 1 <= unit <= 247:
            raise ValueError(f"unit {unit}: a Modbus unit id is 1..247")
        self.unit = unit
        self.function_codes = None if function_codes is None else frozenset(function_codes)
        self.clock: Clock = clock if clock is not None else RealClock()  # scan() gets its time
        self.port = 0
        self._faults: list[tuple[str, int | None]] = []
        self._server: ModbusTcpServer | None = None
        self._loop: LoopThread | None = None
        self.t0 = self.clock.monotonic()

    def start(self) -> Self:
        self._loop = LoopThread(type(self).__name__)
        self._loop.run(self._start())
        self.t0 = self.clock.monotonic()
        return self

    async def _start(self) -> None:
        data = [SimData(0, count=self.size, values=0, datatype=DataType.REGISTERS)]
        devices = [
            SimDevice(id=0 if self.unit is None else self.unit, simdata=data, action=self._action)
        ]
        if self.unit is not None:  # every other unit id lands on device 0: no such device
            devices.append(SimDevice(id=0, simdata=data, action=self._no_such_unit))
        self._server = ModbusTcpServer(devices, address=(self.host, self._want_port))
        await self._server.serve_forever(background=True)
        self.port = self._server.transport.sockets[0].getsockname()[1]  # type: ignore[attr-defined]

    def close(self) -> None:
        if self._loop is not None:
            if self._server is not None:
                self._loop.run(self._server.shutdown())
            self._loop.stop()
            self._loop = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def fail_next(self, mode: str, *, function_code: int | None = None) -> None:
        """Fail the next request (of ``function_code`` only, e.g. 16 = write registers)."""
        self._faults.append((mode, function_code))

    def drop_connections(self) -> None:
        assert self._loop is not None and self._server is not None
        server = self._server

        def _drop() -> None:
            for connection in list(server.active_connections.values()):
                connection.close()

        self._loop.call(_drop)

    def _write_to_clients(self, data: bytes) -> None:
        assert self._server is not None
        for connection in list(self._server.active_connections.values()):
            if isinstance(connection.transport, asyncio.WriteTransport):
                connection.transport.write(data)

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        if self.function_codes is not None and function_code not in self.function_codes:
            return ExcCodes.ILLEGAL_FUNCTION
        if self._faults and self._faults[0][1] in (None, function_code):
            mode = self._faults.pop(0)[0]
            if mode == "exception":
                return ExcCodes.DEVICE_FAILURE
            if mode == "drop":
                self.drop_connections()
                await asyncio.sleep(3600)  # never answered: the connection is gone
            if mode == "garble":
                self._write_to_clients(_GARBLED)
            if mode in ("mute", "garble"):
                await asyncio.sleep(3600)
        if function_code == 6 and not values:
            return None  # pymodbus reading back a single write to echo it: no scan in between
        base = address - start_address
        written = {base + i: int(v) for i, v in enumerate(values or [])}
        self.scan(self.clock.monotonic(), registers, written)
        return None

    async def _no_such_unit(self, *request: object) -> ExcCodes:
        # pymodbus 3.16 turns a unit id it has no device for into a KeyError and exception 4
        # (device failure): answer as its server means to, and as a gateway does
        return ExcCodes.GATEWAY_NO_RESPONSE

    def scan(self, now: float, regs: list[int], written: dict[int, int]) -> None:
        raise NotImplementedError
