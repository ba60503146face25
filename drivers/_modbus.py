"""A blocking Modbus TCP link (pymodbus 3.16, pinned) with its errors translated, and the float32
word packing shared by the robot mailbox and the PLC register map.

pymodbus does not follow semantic versioning (3.10 renamed ``slave=`` to ``device_id=``); this is
the only module of drivers/ that calls it, so a pin bump is checked here. With a trace channel
every request (function code, address, count or words) and its reply or error is traced.

pymodbus logs on its own loggers (`pymodbus.logging`: "Connection to (127.0.0.1, 502) failed:
..." at ERROR). With no handler there Python's last resort printed that raw line on the user's
terminal beside rvis's own message, which already says it (as a device error). Its records go
to rvis's logging instead, as DEBUG records of `rvis.drivers.pymodbus` (their own level in the
text): quiet unless `--log-level debug` asks for them.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Sequence
from typing import Literal

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from drivers.errors import (
    DeviceConnectionError,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
)
from drivers.trace import TraceChannel

WordOrder = Literal["big", "little"]


class _ToRvisDebug(logging.Handler):
    """Every record of pymodbus's logger again as a DEBUG record of `rvis.drivers.pymodbus`."""

    def __init__(self) -> None:
        super().__init__()
        self.target = logging.getLogger("rvis.drivers.pymodbus")

    def emit(self, record: logging.LogRecord) -> None:
        if self.target.isEnabledFor(logging.DEBUG):
            self.target.debug("%s: %s", record.levelname, record.getMessage())


def _route_pymodbus_logs() -> None:
    logger = logging.getLogger("pymodbus")
    if not any(isinstance(h, _ToRvisDebug) for h in logger.handlers):
        logger.addHandler(_ToRvisDebug())
    logger.propagate = False  # nothing of pymodbus's reaches the root logger's handlers


_route_pymodbus_logs()


def floats_to_words(values: Sequence[float], word_order: WordOrder = "little") -> list[int]:
    """IEEE float32 values -> 16-bit words (two per value; the mailbox's REALs: low word first)."""
    words: list[int] = []
    for v in values:
        hi, lo = struct.unpack(">HH", struct.pack(">f", float(v)))
        words += [lo, hi] if word_order == "little" else [hi, lo]
    return words


def words_to_floats(words: Sequence[int], word_order: WordOrder = "little") -> list[float]:
    if len(words) % 2:
        raise ProtocolError(f"odd number of words for float32: {len(words)}")
    out = []
    for i in range(0, len(words), 2):
        a, b = words[i], words[i + 1]
        hi, lo = (b, a) if word_order == "little" else (a, b)
        out.append(struct.unpack(">f", struct.pack(">HH", hi, lo))[0])
    return out


#: Modbus exception codes (Modbus Application Protocol V1.1b3, 7) as an operator reads them.
EXCEPTION_TEXT = {
    1: "illegal function (the server does not offer this function code)",
    2: "illegal data address (the registers are not in the server's map)",
    3: "illegal data value",
    4: "server device failure",
    6: "server device busy",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond (no such unit id behind this address)",
}


def _exception(where: str, what: str, unit: int, rr: object) -> DeviceFault:
    code = int(getattr(rr, "exception_code", 0))
    text = EXCEPTION_TEXT.get(code, str(rr))
    return DeviceFault(f"{where}: {what} (unit {unit}): exception {code}: {text}", code=code)


def require_link(link: ModbusLink | None, name: str) -> ModbusLink:
    """The device's link, or DeviceConnectionError when an earlier reconnect failed (so the
    read-retry policy reconnects again instead of tripping over a missing link)."""
    if link is None:
        raise DeviceConnectionError(f"{name}: not connected")
    return link


class ModbusLink:
    """Holding-register reads and writes to one unit; every failure is a device error."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        unit: int,
        timeout_s: float,
        trace: TraceChannel | None = None,
    ) -> None:
        self.where = f"{host}:{port}"
        self.unit = unit
        self.trace = trace
        self._client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)

    def connect(self) -> None:
        try:
            ok = self._client.connect()
        except ModbusException as exc:
            error = DeviceConnectionError(f"{self.where}: cannot connect: {exc}")
            raise self._noted(error) from exc
        if not ok:
            self._client.close()
            raise self._noted(DeviceConnectionError(f"{self.where}: cannot connect"))

    def close(self) -> None:
        self._client.close()

    def read(self, address: int, count: int) -> list[int]:
        if self.trace is not None:
            self.trace.tx(f"{self.where} unit {self.unit} fc3 read {address} count {count}")
        try:
            rr = self._client.read_holding_registers(address, count=count, device_id=self.unit)
        except (ModbusException, OSError) as exc:
            raise self._noted(self._translate(exc)) from exc
        if rr.isError():
            raise self._noted(_exception(self.where, f"read {address}+{count}", self.unit, rr))
        if len(rr.registers) != count:
            raise self._noted(
                ProtocolError(f"{self.where}: asked {count} registers, got {len(rr.registers)}")
            )
        if self.trace is not None:
            self.trace.rx(f"{self.where} fc3 {address}: {list(rr.registers)}")
        return list(rr.registers)

    def write(self, address: int, values: Sequence[int]) -> None:
        words = list(values)
        if self.trace is not None:
            self.trace.tx(f"{self.where} unit {self.unit} fc16 write {address}: {words}")
        try:
            rr = self._client.write_registers(address, words, device_id=self.unit)
        except (ModbusException, OSError) as exc:
            raise self._noted(self._translate(exc)) from exc
        if rr.isError():
            raise self._noted(_exception(self.where, f"write {address}", self.unit, rr))
        if self.trace is not None:
            self.trace.rx(f"{self.where} fc16 {address}: ok")

    def _noted(self, exc: DeviceError) -> DeviceError:
        """``exc``, written to the trace first (when on)."""
        if self.trace is not None:
            self.trace.note(f"{self.where} {type(exc).__name__}: {exc}")
        return exc

    def _translate(self, exc: ModbusException | OSError) -> DeviceError:
        """A pymodbus error, or the socket's own that pymodbus lets through (a reset by the
        peer mid-exchange: an internal error of the service until 2026-11-30), as rvis's."""
        self._client.close()  # resynchronise the transaction ids on the next connect
        if isinstance(exc, ConnectionException | OSError):
            return DeviceConnectionError(f"{self.where}: {exc}")
        if isinstance(exc, ModbusIOException):
            return DeviceTimeout(f"{self.where}: no valid reply: {exc}")
        return ProtocolError(f"{self.where}: {exc}")
