"""A SCPI DAC board behind a pty pair: the galvo driver opens a real serial port (``.port``).

Answers ``*IDN?``, ``SOUR:VOLT <v>``, ``SOUR:VOLT?``, ``SYST:ERR?`` like the board: a voltage
outside +-10 V or an unknown command queues an error (-222 / -113). A daemon thread serves the
master side. Test controls: ``fail_next(command, mode)`` with mode "mute" (no answer), "garble"
(non-numeric answer), "truncate" (answer without its LF), "drop" (the board vanishes on receipt,
as a USB-CDC device unplugged mid-command), or an int error code queued in place of executing
the command. ``unplug()`` removes the board at once, ``replug()`` brings it back.

With ``link=`` (a path), ``.port`` is a symlink to the pty, re-pointed on ``replug()``: the stable
name udev gives a USB serial device (/dev/serial/by-id/...), so the driver can reopen the same
port after the board has been away. Without it, ``.port`` is the pty itself.

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


class _Vanished(Exception):
    """Raised inside the serving thread when a "drop" fault removes the board."""


class ScpiDac:
    def __init__(self, *, volt_limit: float = 10.0, link: str | os.PathLike[str] | None = None):
        self.volt_limit = volt_limit
        self.volts = 0.0
        self.commands: list[str] = []
        self._errors: list[tuple[int, str]] = []
        self._faults: dict[str, str | int] = {}
        self._link = os.fspath(link) if link is not None else None
        self._master = self._slave = -1
        self._stop_r = self._stop_w = -1
        self._fd_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.port = ""

    def start(self) -> Self:
        self._plug()
        return self

    def close(self) -> None:
        self.unplug()
        if self._link is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self._link)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- test controls ------------------------------------------------------------------------
    def fail_next(self, command: str, mode: str | int) -> None:
        self._faults[command] = mode

    def unplug(self) -> None:
        """The board vanishes: its pty closes, the driver's next read or write fails."""
        thread, self._thread = self._thread, None
        if thread is not None:
            os.write(self._stop_w, b"x")
            thread.join(5.0)
        self._release("_master", "_slave", "_stop_r", "_stop_w")

    def replug(self) -> None:
        """The board comes back on a new pty (behind the same ``link``, if any)."""
        self.unplug()
        self._plug()

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    # -- the pty ------------------------------------------------------------------------------
    def _plug(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        pty = os.ttyname(self._slave)
        if self._link is None:
            self.port = pty
        else:
            fresh = self._link + ".new"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(fresh)
            os.symlink(pty, fresh)
            os.replace(fresh, self._link)  # atomic: the driver never sees a missing link
            self.port = self._link
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(
            target=self._serve, args=(self._master, self._stop_r), name="scpi-dac", daemon=True
        )
        self._thread.start()

    def _release(self, *names: str) -> None:
        with self._fd_lock:
            fds = [getattr(self, name) for name in names]
            for name in names:
                setattr(self, name, -1)
        for fd in fds:
            if fd >= 0:
                os.close(fd)

    def _serve(self, master: int, stop: int) -> None:
        buf = b""
        while True:
            ready, _, _ = select.select([master, stop], [], [])
            if stop in ready:
                return
            try:
                chunk = os.read(master, 4096)
            except OSError:
                return
            buf += chunk
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                try:
                    answer = self._execute(raw.decode("ascii", "replace").strip())
                except _Vanished:
                    self._release("_master", "_slave")
                    return
                if answer is not None:
                    os.write(master, answer)

    def _execute(self, line: str) -> bytes | None:
        self.commands.append(line)
        header = line.split(" ", 1)[0].upper()
        mode = self._faults.pop(header, None)
        if mode == "mute":
            return None
        if mode == "drop":
            raise _Vanished(line)
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
