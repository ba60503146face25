"""Galvo DAC speaking SCPI over a serial port: ``scpi+serial:///dev/ttyACM0?baud=115200``.

Works with any SCPI / IEEE 488.2 conforming board, using only what the standards require:
``*CLS`` on open (clear the error queue and the status), ``*IDN?`` (identity), ``:SOUR:VOLT <v>``
(set the output voltage; the short forms of ``[:SOURce]:VOLTage``), ``:SOUR:VOLT?`` (read it back:
any NR1/NR2/NR3 number), ``:SYST:ERR?`` (pop the error queue until ``0,"No error"``, with or
without a sign, quoted or not). Messages end with LF; answers with LF or CR LF. pyserial URLs work
too (``loop://``, ``socket://host:port``). serial.SerialException (and the OSError or
termios.error pyserial lets through when the port vanishes while it is opened or drained) ->
DeviceConnectionError, no line within the timeout -> DeviceTimeout, an unparsable answer ->
ProtocolError. Traced (``?trace=1``): every line sent and answered, and the errors.
"""

from __future__ import annotations

import re
from typing import Any

import serial

from drivers.errors import (
    DeviceConfigError,
    DeviceConnectionError,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
)
from drivers.galvo import Galvo
from drivers.url import DeviceUrl

_ERR = re.compile(r'^\s*([+-]?\d+)\s*,\s*"?(.*?)"?\s*$')

# What pyserial raises when the port fails or vanishes (termios.error is not an OSError).
_PORT_ERRORS: tuple[type[Exception], ...] = (serial.SerialException, OSError)
try:
    import termios

    _PORT_ERRORS += (termios.error,)
except ImportError:  # Windows: pyserial does not use termios there
    pass
_OPEN_ERRORS: tuple[type[Exception], ...] = (*_PORT_ERRORS, ValueError)  # bad settings


class ScpiGalvo(Galvo):
    """``ScpiGalvo("/dev/ttyACM0", baud=115200, settings=GalvoSettings(-10.0, 10.0))``."""

    def __init__(self, port: str, *, baud: int = 115200, **kw: Any) -> None:
        kw.setdefault("name", f"scpi+serial://{port}")
        super().__init__(**kw)
        self.port, self.baud = port, int(baud)
        self._serial: serial.SerialBase | None = None
        self.identity = ""

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> ScpiGalvo:
        if not url.path:
            raise DeviceConfigError(f"{url.raw}: no serial port path")
        options.setdefault("baud", int(url.number("baud", 115200)))
        return cls(url.path, **options)

    def _open(self) -> None:
        try:
            self._serial = serial.serial_for_url(
                self.port,
                baudrate=self.baud,
                timeout=self.timeout_s,
                write_timeout=self.timeout_s,
            )
            self._serial.reset_input_buffer()
        except _OPEN_ERRORS as exc:
            raise DeviceConnectionError(f"{self.name}: cannot open: {exc}") from exc
        self._write("*CLS")  # errors and events left from before are not ours
        self.identity = self._identify()

    def _close(self) -> None:
        port, self._serial = self._serial, None
        if port is not None:
            port.close()

    def describe(self) -> str:
        self._check_open()
        return self.identity

    def _identify(self) -> str:
        return self._query("*IDN?")

    def _set_volts(self, volts: float) -> None:
        self._write(f":SOUR:VOLT {volts:.6f}")

    def _get_volts(self) -> float:
        answer = self._query(":SOUR:VOLT?")
        try:
            return float(answer)
        except ValueError as exc:
            raise ProtocolError(f"{self.name}: SOUR:VOLT? answered {answer!r}") from exc

    def _errors(self) -> list[tuple[int, str]]:
        errors = []
        for _ in range(32):  # the queue is finite; do not loop forever on a broken device
            answer = self._query(":SYST:ERR?")
            match = _ERR.match(answer)
            if match is None:
                raise ProtocolError(f"{self.name}: SYST:ERR? answered {answer!r}")
            code = int(match.group(1))
            if code == 0:
                break
            errors.append((code, match.group(2)))
        return errors

    def _write(self, command: str) -> None:
        if self._serial is None:
            raise DeviceConnectionError(f"{self.name}: not open")
        if self.trace is not None:
            self.trace.tx(command)
        try:
            self._serial.write(command.encode("ascii") + b"\n")
            self._serial.flush()
        except serial.SerialTimeoutException as exc:
            raise self._noted(DeviceTimeout(f"{self.name}: write timed out")) from exc
        except _PORT_ERRORS as exc:
            raise self._noted(DeviceConnectionError(f"{self.name}: write failed: {exc}")) from exc

    def _query(self, command: str) -> str:
        self._write(command)
        assert self._serial is not None
        try:
            line = self._serial.readline()
        except _PORT_ERRORS as exc:
            raise self._noted(DeviceConnectionError(f"{self.name}: read failed: {exc}")) from exc
        if self.trace is not None:
            self.trace.rx(line.decode("ascii", errors="replace").rstrip("\r\n"))
        if not line.endswith(b"\n"):
            if line:
                raise self._noted(
                    ProtocolError(f"{self.name}: truncated answer to {command}: {line!r}")
                )
            raise self._noted(
                DeviceTimeout(f"{self.name}: no answer to {command} in {self.timeout_s:g} s")
            )
        try:
            return line.decode("ascii").strip()
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"{self.name}: non-ASCII answer {line!r}") from exc

    def _noted(self, exc: DeviceError) -> DeviceError:
        """``exc``, written to the trace first (when on)."""
        if self.trace is not None:
            self.trace.note(f"{type(exc).__name__}: {exc}")
        return exc
