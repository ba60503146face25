"""A SCPI DAC board behind a pty pair: the galvo driver opens a real serial port (``.port``).

Answers ``*IDN?``, ``SOUR:VOLT <v>``, ``SOUR:VOLT?``, ``SYST:ERR?`` like the board: a voltage
outside +-10 V or an unknown command queues an error (-222 / -113). A daemon thread serves the
master side. Test controls: ``fail_next(command, mode)`` with mode "mute" (no answer), "garble"
(non-numeric answer), "truncate" (answer without its LF), or an int error code queued in place
of executing the command.

    with ScpiDac() as dac:
        galvo = ScpiGalvo(dac.port)
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from typing import Self

IDN = "rvis,FakeDAC-1,0001,1.0"


class ScpiDac:
    def __init__(self, *, volt_limit: float = 10.0) -> None:
        self.volt_limit = volt_limit
        self.volts = 0.0
        self.commands: list[str] = []
        self._errors: list[tuple[int, str]] = []
        self._faults: dict[str, str | int] = {}
        self._master = self._slave = -1
        self._stop_r = self._stop_w = -1
        self._thread: threading.Thread | None = None
        self.port = ""

    def start(self) -> Self:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._serve, name="scpi-dac", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        if self._thread is None:
            return
        os.write(self._stop_w, b"x")
        self._thread.join(5.0)
        self._thread = None
        for fd in (self._master, self._slave, self._stop_r, self._stop_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def fail_next(self, command: str, mode: str | int) -> None:
        self._faults[command] = mode

    def _serve(self) -> None:
        buf = b""
        while True:
            ready, _, _ = select.select([self._master, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                chunk = os.read(self._master, 4096)
            except OSError:
                return
            buf += chunk
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                answer = self._execute(raw.decode("ascii", "replace").strip())
                if answer is not None:
                    os.write(self._master, answer)

    def _execute(self, line: str) -> bytes | None:
        self.commands.append(line)
        header = line.split(" ", 1)[0].upper()
        mode = self._faults.pop(header, None)
        if mode == "mute":
            return None
        if isinstance(mode, int):
            self._errors.append((mode, "Injected error"))
            return b"0\n" if header.endswith("?") else None
        answer = self._answer(header, line)
        if answer is None:
            return None
        if mode == "garble":
            return b"\xff?!\n"
        if mode == "truncate":
            return answer.encode()[: max(1, len(answer) // 2)]
        return answer.encode() + b"\n"

    def _answer(self, header: str, line: str) -> str | None:
        if header == "*IDN?":
            return IDN
        if header in ("SOUR:VOLT?", "SOURCE:VOLTAGE?"):
            return f"{self.volts:.6f}"
        if header == "SYST:ERR?":
            code, msg = self._errors.pop(0) if self._errors else (0, "No error")
            return f'{code},"{msg}"'
        if header in ("SOUR:VOLT", "SOURCE:VOLTAGE"):
            try:
                value = float(line.split(" ", 1)[1])
            except (IndexError, ValueError):
                self._errors.append((-104, "Data type error"))
                return None
            if abs(value) > self.volt_limit:
                self._errors.append((-222, "Data out of range"))
            else:
                self.volts = value
            return None
        self._errors.append((-113, "Undefined header"))
        return None
