"""Line PLC handshake over Modbus TCP: ``plc+modbus://host:502?unit=1&base=0``.

Holding registers (16-bit words) relative to ``base``; the PLC is the server:

    word 0   PLC_STATUS     bit 0 window_open, bit 1 line_running        (PLC writes)
    word 1   PLC_HEARTBEAT  incremented by the PLC at least every second  (PLC writes)
    word 2   PLC_CELL_TEMP  cell air temperature, signed 0.01 degC; 0x8000 none (PLC writes)
    word 3-6 PLC_BODY_ID    the clamped body's id: "u32" in words 3-4 (high word first, 0 none)
                            or "serial8" in words 3-6 (8 ASCII, 2 a word)   (PLC writes)
    word 10  APP_STATUS     bit 0 busy, bit 1 done, bit 2 fault           (app writes)
    word 11  APP_HEARTBEAT  incremented by the app on every poll         (app writes)

The bits are the family's (drivers/plc.py); the app reads words 0-2 and writes words 10-11,
each in one request (and reads 10-11 back for a check), and, when the cell file asks for the
body id (`[line] plc_body_id`), words 3-4 or 3-6 in one request at each window's rising edge;
to the PLC's unit id (``unit``, default 1), with function codes 3 (read holding registers) and
16 (write multiple registers) only; a PLC server that also offers 6 (write single register)
serves the map as well. ``?read_only=1``:
never write. Safety interlocks are not here: they stay in the safety PLC.
"""

from __future__ import annotations

from typing import Any

from drivers._modbus import ModbusLink, require_link
from drivers.plc import Plc
from drivers.url import DeviceUrl

DEFAULT_PORT = 502
DEFAULT_UNIT = 1
#: The function codes of the register map: read holding registers, write single register,
#: write multiple registers (the driver uses 3 and 16).
FUNCTION_CODES = (3, 6, 16)
PLC_STATUS, PLC_HEARTBEAT, PLC_CELL_TEMP, APP_STATUS, APP_HEARTBEAT = 0, 1, 2, 10, 11
PLC_BODY_ID = 3  # 2 (u32) or 4 (serial8) words
REGISTER_COUNT = 12


class ModbusPlc(Plc):
    """``ModbusPlc("10.0.0.2", 502, unit=1, base=0, heartbeat_timeout_s=3, poll_s=0.1)``."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        unit: int = DEFAULT_UNIT,
        base: int = 0,
        **kw: Any,
    ) -> None:
        kw.setdefault("name", f"plc+modbus://{host}:{port}")
        super().__init__(**kw)
        self.host, self.port, self.unit, self.base = host, int(port), int(unit), int(base)
        self._link: ModbusLink | None = None

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> ModbusPlc:
        host, port = url.address(DEFAULT_PORT)
        options.setdefault("unit", int(url.number("unit", DEFAULT_UNIT)))
        options.setdefault("base", int(url.number("base", 0)))
        options.setdefault("read_only", url.flag("read_only"))
        return cls(host, port, **options)

    def describe(self) -> str:
        self._check_open()
        return f"line PLC at {self.host}:{self.port} unit {self.unit} base {self.base}"

    def _connect(self) -> None:
        link = ModbusLink(
            self.host, self.port, unit=self.unit, timeout_s=self.timeout_s, trace=self.trace
        )
        link.connect()
        self._link = link

    def _close(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link.close()

    def _read_input_words(self) -> tuple[int, ...]:
        status, beat, temp = require_link(self._link, self.name).read(self.base + PLC_STATUS, 3)
        return status, beat, temp

    def _read_body_words(self, count: int) -> tuple[int, ...]:
        return tuple(require_link(self._link, self.name).read(self.base + PLC_BODY_ID, count))

    def _write_output_words(self, words: tuple[int, int]) -> None:
        require_link(self._link, self.name).write(self.base + APP_STATUS, list(words))

    def _read_output_words(self) -> tuple[int, int]:
        status, beat = require_link(self._link, self.name).read(self.base + APP_STATUS, 2)
        return status, beat
