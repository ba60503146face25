"""The line-PLC family: the clamp-window handshake (process signals only; safety interlocks stay
in the safety PLC).

Signals, as two 16-bit words each way (the register map of every backend; README "Connecting
real hardware"):

    PLC -> app   status word   bit 0 window_open (the clamps leave the robot a window to measure),
                               bit 1 line_running (the line is in automatic),
                               bit 2 body_ready (a body is clamped and the robot may measure
                               its features; the body id words hold it)
                 heartbeat     a counter the PLC increments (at least every second)
                 cell temp     optional third word: the cell's air temperature in 0.01 degC,
                               signed 16 bit; 0x8000 = no sensor (a backend may omit the word)
                 body id       optional words after it: the clamped body's identifier, held
                               from before the window opens until it closes; "u32": a 32-bit
                               body number in two words, high word first (0 = no body),
                               "serial8": up to 8 ASCII characters in four words, two a word,
                               the first in the high byte, NUL- or space-padded (blank = no
                               body). Read once at each window's rising edge (`read_body_id`)
    app -> PLC   status word   bit 0 busy (the robot is out of home / measuring), bit 1 done (the
                               measurement finished and the robot is home), bit 2 fault (the app
                               has a fault; the PLC must not wait for done), bit 3 body_done
                               (the body's features are measured and stored, the robot home),
                               bit 4 body_nok (with body_done: a characteristic proven out of
                               tolerance or not measured), both held until body_ready falls
                 heartbeat     a counter the app increments on every poll

The whole handshake is here: decoding and encoding the words, the heartbeat counter and the
heartbeat-alive check (a PLC heartbeat unchanged for ``heartbeat_timeout_s`` means "not ready"),
the window wait (polls with a deadline, ``poll_s``), busy/done/fault around a window, and the
outputs reset to zero on every connect. A backend implements only the transport and two
register-level primitives: ``_connect()``, ``_close()``, ``_read_input_words() -> (status,
heartbeat[, cell temp])``, ``_write_output_words((status, heartbeat))`` and
``_read_output_words() -> (status, heartbeat)`` (the app's words as the PLC holds them); a
backend that has the body id words also ``_read_body_words(count)``.

``read_only=True`` (URL option ``?read_only=1``) opens a connection that never writes: no reset
of the outputs on connect, no heartbeat on poll, and every write (``set_signals``, ``window``)
is refused with DeviceConfigError. `rvis devices check` and the contract tests on a real PLC
use it, so that looking at a live line never changes its handshake.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceTimeout

WINDOW_OPEN, LINE_RUNNING, BODY_READY = 0x1, 0x2, 0x4  # PLC status word bits
BUSY, DONE, FAULT, BODY_DONE, BODY_NOK = 0x1, 0x2, 0x4, 0x8, 0x10  # app status word bits
NO_TEMPERATURE = 0x8000  # the cell temperature word when the PLC has no sensor
#: the body id's formats and their word counts (module docstring)
BODY_ID_WORDS = {"u32": 2, "serial8": 4}
BodyId = int | str


@dataclass(frozen=True)
class PlcInputs:
    window_open: bool
    line_running: bool
    heartbeat: int
    temp_c: float | None = None  # the cell's air temperature [degC], None without a sensor
    body_ready: bool = False  # a body is clamped for its features to be measured


@dataclass(frozen=True)
class PlcOutputs:
    busy: bool = False
    done: bool = False
    fault: bool = False
    heartbeat: int = 0
    body_done: bool = False
    body_nok: bool = False


def decode_temp(word: int) -> float | None:
    """Signed 0.01 degC -> degC (NO_TEMPERATURE -> None)."""
    word = int(word) & 0xFFFF
    if word == NO_TEMPERATURE:
        return None
    return (word - 0x10000 if word & 0x8000 else word) / 100.0


def encode_temp(temp_c: float | None) -> int:
    """degC -> signed 0.01 degC (None -> NO_TEMPERATURE); clamped to the word's range."""
    if temp_c is None:
        return NO_TEMPERATURE
    centi = max(-32767, min(32767, round(float(temp_c) * 100.0)))
    return centi & 0xFFFF


def _body_words(fmt: str) -> int:
    if fmt not in BODY_ID_WORDS:
        raise DeviceConfigError(f"body id format {fmt!r}: one of {', '.join(BODY_ID_WORDS)}")
    return BODY_ID_WORDS[fmt]


def decode_body_id(words: Sequence[int], fmt: str) -> BodyId | None:
    """The body id words in format `fmt` -> the body number (u32) or serial (serial8); None
    when the PLC says no body is clamped (0, blank)."""
    n = _body_words(fmt)
    words = [int(w) & 0xFFFF for w in words[:n]]
    if len(words) < n:
        return None
    if fmt == "u32":
        number = (words[0] << 16) | words[1]
        return number or None
    raw = b"".join(w.to_bytes(2, "big") for w in words)
    text = raw.rstrip(b"\0 ").decode("ascii", errors="replace")
    return text.strip() or None


def encode_body_id(body: BodyId | None, fmt: str) -> tuple[int, ...]:
    """A body number or serial -> its words in format `fmt` (None: no body)."""
    n = _body_words(fmt)
    if body is None:
        return (0,) * n
    if fmt == "u32":
        number = int(body) & 0xFFFFFFFF
        return number >> 16, number & 0xFFFF
    raw = str(body).encode("ascii", errors="replace")[: 2 * n].ljust(2 * n, b"\0")
    return tuple(int.from_bytes(raw[k : k + 2], "big") for k in range(0, 2 * n, 2))


def decode_inputs(words: Sequence[int]) -> PlcInputs:
    """(status, heartbeat) or (status, heartbeat, cell temperature) -> PlcInputs."""
    status, beat = words[0], words[1]
    return PlcInputs(
        window_open=bool(status & WINDOW_OPEN),
        line_running=bool(status & LINE_RUNNING),
        heartbeat=int(beat) & 0xFFFF,
        temp_c=decode_temp(words[2]) if len(words) > 2 else None,
        body_ready=bool(status & BODY_READY),
    )


def encode_inputs(inputs: PlcInputs) -> tuple[int, int]:
    bits = (WINDOW_OPEN if inputs.window_open else 0) | (LINE_RUNNING if inputs.line_running else 0)
    bits |= BODY_READY if inputs.body_ready else 0
    return bits, inputs.heartbeat & 0xFFFF


def encode_outputs(out: PlcOutputs) -> tuple[int, int]:
    bits = (BUSY if out.busy else 0) | (DONE if out.done else 0) | (FAULT if out.fault else 0)
    bits |= (BODY_DONE if out.body_done else 0) | (BODY_NOK if out.body_nok else 0)
    return bits, out.heartbeat & 0xFFFF


def decode_outputs(words: tuple[int, int]) -> PlcOutputs:
    bits, beat = words
    return PlcOutputs(
        busy=bool(bits & BUSY),
        done=bool(bits & DONE),
        fault=bool(bits & FAULT),
        heartbeat=int(beat) & 0xFFFF,
        body_done=bool(bits & BODY_DONE),
        body_nok=bool(bits & BODY_NOK),
    )


class Plc(Device):
    """The line PLC's process handshake."""

    family = "plc"

    def __init__(
        self,
        *,
        timeout_s: float = 2.0,
        heartbeat_timeout_s: float = 3.0,
        poll_s: float = 0.1,
        read_only: bool = False,
        name: str = "",
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        if not (heartbeat_timeout_s > 0 and poll_s > 0):
            raise DeviceConfigError("heartbeat_timeout_s and poll_s must be > 0")
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.poll_s = float(poll_s)
        self.read_only = bool(read_only)
        self._out = PlcOutputs()
        self._last_beat: tuple[int, float] | None = None

    @property
    def outputs(self) -> PlcOutputs:
        return self._out

    def poll(self) -> PlcInputs:
        """Read the inputs and send our heartbeat (one exchange; read-only: no heartbeat)."""
        inputs = decode_inputs(self._read_retrying(self._read_input_words))
        now = time.monotonic()
        if self._last_beat is None or self._last_beat[0] != inputs.heartbeat:
            self._last_beat = (inputs.heartbeat, now)
        if not self.read_only:
            self._send(replace(self._out, heartbeat=(self._out.heartbeat + 1) & 0xFFFF))
        return inputs

    def read_body_id(self, fmt: str) -> BodyId | None:
        """The clamped body's identifier in format `fmt` (BODY_ID_WORDS), one request; None when
        the PLC says no body, or the backend has no body id words."""
        n = _body_words(fmt)
        words = self._read_retrying(lambda: self._read_body_words(n))
        return None if words is None else decode_body_id(words, fmt)

    def read_outputs(self) -> PlcOutputs:
        """The app's status and heartbeat words as the PLC holds them (read back)."""
        return decode_outputs(self._read_retrying(self._read_output_words))

    def heartbeat_alive(self) -> bool:
        """True when the PLC heartbeat changed within ``heartbeat_timeout_s``."""
        if self._last_beat is None:
            return False
        return time.monotonic() - self._last_beat[1] <= self.heartbeat_timeout_s

    def ready(self) -> bool:
        """The PLC is alive, the line running and the clamp window open."""
        inputs = self.poll()
        return inputs.window_open and inputs.line_running and self.heartbeat_alive()

    def wait_window(self, timeout_s: float) -> PlcInputs:
        """Poll until the window is open (line running, heartbeat alive); DeviceTimeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            inputs = self.poll()
            alive = self.heartbeat_alive()
            if inputs.window_open and inputs.line_running and alive:
                return inputs
            if time.monotonic() >= deadline:
                why = "PLC heartbeat lost" if not alive else "line not running"
                why = why if (not alive or not inputs.line_running) else "window closed"
                raise DeviceTimeout(f"{self.name}: no clamp window within {timeout_s:g} s ({why})")
            time.sleep(self.poll_s)

    def set_signals(self, *, busy: bool, done: bool, fault: bool) -> None:
        self._send(replace(self._out, busy=busy, done=done, fault=fault))

    def set_body_signals(self, *, done: bool, nok: bool = False) -> None:
        """The body's result bits (held until body_ready falls: the caller clears them)."""
        self._send(replace(self._out, body_done=done, body_nok=nok and done))

    @contextmanager
    def window(self, timeout_s: float) -> Iterator[PlcInputs]:
        """Wait for the window, hold ``busy`` inside; ``done`` after, ``fault`` on an error."""
        inputs = self.wait_window(timeout_s)
        self.set_signals(busy=True, done=False, fault=False)
        try:
            yield inputs
        except BaseException:
            self.set_signals(busy=False, done=False, fault=True)
            raise
        self.set_signals(busy=False, done=True, fault=False)

    def _send(self, outputs: PlcOutputs) -> None:
        self._check_open()
        if self.read_only:
            raise DeviceConfigError(f"{self.name}: opened read-only; outputs are not written")
        words = encode_outputs(outputs)
        self._read_retrying(lambda: self._write_output_words(words))  # idempotent: an image
        self._out = outputs

    def _open(self) -> None:
        """Connect, then reset the outputs: not busy, not done, no fault, heartbeat 0 (not when
        read-only)."""
        self._connect()
        self._out = PlcOutputs()
        self._last_beat = None
        if not self.read_only:
            self._write_output_words(encode_outputs(self._out))

    @abstractmethod
    def _connect(self) -> None:
        """Open the transport (the base class resets the outputs after it)."""

    @abstractmethod
    def _read_input_words(self) -> tuple[int, ...]:
        """The PLC's (status word, heartbeat word) or (status, heartbeat, cell temperature)."""

    def _read_body_words(self, count: int) -> tuple[int, ...] | None:
        """The `count` body id words (None: this backend has none)."""
        return None

    @abstractmethod
    def _write_output_words(self, words: tuple[int, int]) -> None:
        """Write the app's (status word, heartbeat word) in one request."""

    @abstractmethod
    def _read_output_words(self) -> tuple[int, int]:
        """Read the app's (status word, heartbeat word) back from the PLC."""
