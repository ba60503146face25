"""A pymodbus server playing the line PLC (register map in drivers/plc_modbus.py): it runs a
ClampCycle (for example an 8 s window every 60 s, compressed by ``time_scale`` in tests) and
records what the app writes. Like a PLC it answers only its unit id (``unit``, default 1) and
the function codes of the register map (3, 6, 16; any other: exception 0x01, illegal function).
``heartbeat_frozen = True`` simulates a stalled PLC;
``temperature`` (a callable returning degC, or None for "no sensor", 0x8000) feeds the cell
temperature word; left None, the PLC program never writes the word and it stays 0, as in a PLC
program that predates the temperature input. The PLC counts bodies: each clamp period holds the
next body number (`ClampCycle.body`: ``first_body`` + the period's index) in the body id words
in ``body_format`` ("u32" by default, "serial8": `fakes.devices.body_id_of`; None: never
written, 0).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from drivers.plc import PlcOutputs, decode_outputs, encode_body_id, encode_inputs, encode_temp
from drivers.plc_modbus import (
    APP_STATUS,
    DEFAULT_UNIT,
    FUNCTION_CODES,
    PLC_BODY_ID,
    PLC_CELL_TEMP,
    PLC_STATUS,
    REGISTER_COUNT,
)
from fakes._modbus_server import RegisterServer
from fakes.devices import ClampCycle, body_id_of, signals_of


class PlcServer(RegisterServer):
    """``with PlcServer(ClampCycle(time_scale=0.01)) as plc: ModbusPlc("127.0.0.1", plc.port)``"""

    def __init__(
        self, cycle: ClampCycle | None = None, *, base: int = 0, unit: int = DEFAULT_UNIT, **kw: Any
    ) -> None:
        super().__init__(size=base + REGISTER_COUNT, unit=unit, function_codes=FUNCTION_CODES, **kw)
        self.cycle = cycle or ClampCycle()
        self.base = base
        self.heartbeat_frozen = False
        self.temperature: Callable[[], float | None] | None = None
        self.body_format: str | None = "u32"
        self.received = PlcOutputs()
        # the newest 1000 changes the app made, in order (bounded: soaks run for days)
        self.history: deque[PlcOutputs] = deque(maxlen=1000)

    def scan(self, now: float, regs: list[int], written: dict[int, int]) -> None:
        inputs = self.cycle.inputs(now - self.t0, self.heartbeat_frozen)
        p = self.base + PLC_STATUS
        regs[p : p + 2] = encode_inputs(inputs)
        if self.temperature is not None:
            regs[self.base + PLC_CELL_TEMP] = encode_temp(self.temperature())
        if self.body_format is not None:
            words = encode_body_id(self.body(now - self.t0), self.body_format)
            p = self.base + PLC_BODY_ID
            regs[p : p + len(words)] = words
        a = self.base + APP_STATUS
        if a in written or a + 1 in written:
            out = decode_outputs((written.get(a, regs[a]), written.get(a + 1, regs[a + 1])))
            changed = signals_of(out) != signals_of(self.received)
            if changed:
                self.history.append(out)
            self.received = out

    def body(self, elapsed_s: float) -> int | str:
        """The id of the body clamped `elapsed_s` after the cycle's start, as this PLC writes it."""
        return body_id_of(self.cycle.body(elapsed_s), self.body_format or "u32")
