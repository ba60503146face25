"""A SCPI DAC board behind a pty pair: the galvo driver opens a real serial port (``.port``).

A conforming SCPI / IEEE 488.2 instrument (the message layer is fakes/_scpi.py: long and short
forms, any case, leading colon, compound ``;`` messages, the mandatory common commands, the
standard error numbers). Its own command: ``[:SOURce]:VOLTage[:LEVel][:IMMediate][:AMPLitude]
<numeric value>`` and its query (NR3 answer); a voltage outside +-10 V is -222 "Data out of range"
and leaves the output unchanged; ``*RST`` sets 0 V. A daemon thread serves the master side; a
program message ends with LF (a CR before it is ignored). Test controls: ``fail_next(command,
mode)`` for a command key (``SOUR:VOLT``, ``SOUR:VOLT?``, ``SYST:ERR?``, ``*IDN?``, whatever form
the client used) with mode "mute" (no answer), "garble" (non-numeric answer), "truncate" (answer
without its LF), "drop" (the board vanishes on receipt, as a USB-CDC device unplugged
mid-command), or an int error code queued in place of executing the command. ``unplug()`` removes
the board at once, ``replug()`` brings it back.

On the simulated line's VirtualClock (``clock=``) a voltage command lets ``settle_s`` of sim time
pass: the mirror settling at its new angle.

With ``link=`` (a path), ``.port`` is a symlink to the pty, re-pointed on ``replug()``: the stable
name udev gives a USB serial device (/dev/serial/by-id/...), so the driver can reopen the same
port after the board has been away. A link left there by a killed process is replaced, never
followed. Without it, ``.port`` is the pty itself.

    with ScpiDac() as dac:
        galvo = ScpiGalvo(dac.port)
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import tty
from typing import ClassVar, Self

from fakes._scpi import ScpiError, ScpiInstrument, parse_number
from fakes.clock import VirtualClock

IDN = "rvis,FakeDAC-1,0001,1.0"


class _Vanished(Exception):
    """Raised inside the serving thread when a "drop" fault removes the board."""


class _Muted(Exception):
    """A "mute" fault: the unit is swallowed without an answer."""


def _replace_link(link: str, target: str) -> None:
    """Point the symlink `link` at `target` atomically (the driver never sees it missing). A
    link left by a process killed before it could remove it is replaced, never followed (it
    may name a pty that is another program's now: nothing is written or renamed there); a
    file or folder in the link's place is refused."""
    fresh = link + ".new"
    for path in (link, fresh):
        if os.path.lexists(path) and not os.path.islink(path):
            raise FileExistsError(f"{path}: not a symlink (the DAC's stable name goes there)")
    with contextlib.suppress(FileNotFoundError):
        os.unlink(fresh)  # a symlink: unlink removes the link, never what it points to
    os.symlink(target, fresh)
    os.replace(fresh, link)  # rename(2) replaces the link itself


class ScpiDac(ScpiInstrument):
    commands: ClassVar[tuple[tuple[str, str], ...]] = (
        ("[:SOURce]:VOLTage[:LEVel][:IMMediate][:AMPLitude]", "_voltage"),
    )
    identity = IDN

    def __init__(
        self,
        *,
        volt_limit: float = 10.0,
        link: str | os.PathLike[str] | None = None,
        clock: VirtualClock | None = None,
        settle_s: float = 0.0,
    ):
        super().__init__()
        self.volt_limit = volt_limit
        self.clock, self.settle_s = clock, float(settle_s)
        self.volts = 0.0
        self.commands_received: list[str] = []
        self._faults: dict[str, str | int] = {}
        self._reply_mode: str | None = None
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
            _replace_link(self._link, pty)
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
        self.commands_received.append(line)
        self._reply_mode = None
        answer = self.execute(line)
        if answer is None:
            return None
        if self._reply_mode == "garble":
            return b"\xff?!\n"
        if self._reply_mode == "truncate":
            return answer.encode()[: max(1, len(answer) // 2)]
        return answer.encode() + b"\n"

    def execute(self, message: str) -> str | None:
        try:
            return super().execute(message)
        except _Muted:
            return None

    # -- the instrument -----------------------------------------------------------------------
    def key_of(self, handler: str) -> str:
        return "SOUR:VOLT" if handler == "_voltage" else super().key_of(handler)

    def before_unit(self, key: str) -> None:
        mode = self._faults.pop(key, None)
        if mode == "mute":
            raise _Muted(key)
        if mode == "drop":
            raise _Vanished(key)
        if isinstance(mode, int):
            raise ScpiError(mode, "Injected error")
        if mode in ("garble", "truncate"):
            self._reply_mode = mode

    def reset(self) -> None:
        self.volts = 0.0

    def _voltage(self, query: bool, params: list[str]) -> str | None:
        if query:
            if params and params[0].upper() not in ("MIN", "MINIMUM", "MAX", "MAXIMUM"):
                raise ScpiError(-108)
            if params:
                return f"{(-1 if params[0].upper().startswith('MIN') else 1) * self.volt_limit:E}"
            return f"{self.volts:E}"
        if not params:
            raise ScpiError(-109)
        if len(params) > 1:
            raise ScpiError(-108)
        value = parse_number(params[0], -self.volt_limit, self.volt_limit, 0.0)
        if abs(value) > self.volt_limit:
            raise ScpiError(-222)
        self.volts = value
        if self.clock is not None:
            self.clock.elapse(self.settle_s)  # the mirror settles at its new angle
        return None
