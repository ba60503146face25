"""Line PLC handshake over Modbus TCP: ``plc+modbus://host:502?unit=1&base=0``.

Holding registers (16-bit words) relative to ``base``; the PLC is the server:

    word 0   PLC_STATUS     bit 0 window_open, bit 1 line_running        (PLC writes)
    word 1   PLC_HEARTBEAT  incremented by the PLC at least every second  (PLC writes)
    word 10  APP_STATUS     bit 0 busy, bit 1 done, bit 2 fault           (app writes)
    word 11  APP_HEARTBEAT  incremented by the app on every poll         (app writes)

The app writes words 10-11 in one request. Safety interlocks are not here: they stay in the
safety PLC.
"""

from __future__ import annotations

from typing import Any

from drivers._modbus import ModbusLink, require_link
from drivers.plc import Plc, PlcInputs, PlcOutputs
from drivers.registry import DeviceUrl

DEFAULT_PORT = 502
PLC_STATUS, PLC_HEARTBEAT, APP_STATUS, APP_HEARTBEAT = 0, 1, 10, 11
WINDOW_OPEN, LINE_RUNNING = 0x1, 0x2
BUSY, DONE, FAULT = 0x1, 0x2, 0x4
REGISTER_COUNT = 12


def encode_outputs(out: PlcOutputs) -> list[int]:
    bits = (BUSY if out.busy else 0) | (DONE if out.done else 0) | (FAULT if out.fault else 0)
    return [bits, out.heartbeat & 0xFFFF]


def decode_outputs(words: list[int]) -> PlcOutputs:
    bits, beat = words
    return PlcOutputs(
        busy=bool(bits & BUSY), done=bool(bits & DONE), fault=bool(bits & FAULT), heartbeat=beat
    )


class ModbusPlc(Plc):
    """``ModbusPlc("10.0.0.2", 502, unit=1, base=0, heartbeat_timeout_s=3, poll_s=0.1)``."""

    def __init__(
        self, host: str, port: int = DEFAULT_PORT, *, unit: int = 1, base: int = 0, **kw: Any
    ) -> None:
        kw.setdefault("name", f"plc+modbus://{host}:{port}")
        super().__init__(**kw)
        self.host, self.port, self.unit, self.base = host, int(port), int(unit), int(base)
        self._link: ModbusLink | None = None

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> ModbusPlc:
        host, port = url.address(DEFAULT_PORT)
        options.setdefault("unit", int(url.number("unit", 1)))
        options.setdefault("base", int(url.number("base", 0)))
        return cls(host, port, **options)

    def describe(self) -> str:
        self._check_open()
        return f"line PLC at {self.host}:{self.port} unit {self.unit} base {self.base}"

    def _open(self) -> None:
        link = ModbusLink(self.host, self.port, unit=self.unit, timeout_s=self.timeout_s)
        link.connect()
        self._link = link
        self._open_handshake()
        link.write(self.base + APP_STATUS, encode_outputs(PlcOutputs()))

    def _close(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link.close()

    def _read_inputs(self) -> PlcInputs:
        status, beat = require_link(self._link, self.name).read(self.base + PLC_STATUS, 2)
        return PlcInputs(
            window_open=bool(status & WINDOW_OPEN),
            line_running=bool(status & LINE_RUNNING),
            heartbeat=beat,
        )

    def _write_outputs(self, outputs: PlcOutputs) -> None:
        require_link(self._link, self.name).write(self.base + APP_STATUS, encode_outputs(outputs))
