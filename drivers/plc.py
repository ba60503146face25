"""The line-PLC family: the clamp-window handshake (process signals only; safety interlocks stay
in the safety PLC).

Signals (see README "Connecting real hardware" for the register table):

    PLC -> app   window_open   the clamps leave the robot a window to measure
                 line_running  the line is in automatic
                 heartbeat     a counter the PLC increments (at least every second)
    app -> PLC   busy          the robot is out of its home position / measuring
                 done          the measurement finished and the robot is home
                 fault         the app has a fault; the PLC must not wait for done
                 heartbeat     a counter the app increments on every poll

A PLC heartbeat that has not changed for ``heartbeat_timeout_s`` means "not ready". Backend
primitives: ``_read_inputs() -> PlcInputs`` and ``_write_outputs(PlcOutputs)``. Waiting polls with
a deadline (``poll_s``).
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace

from drivers.base import Device
from drivers.errors import DeviceConfigError, DeviceTimeout


@dataclass(frozen=True)
class PlcInputs:
    window_open: bool
    line_running: bool
    heartbeat: int


@dataclass(frozen=True)
class PlcOutputs:
    busy: bool = False
    done: bool = False
    fault: bool = False
    heartbeat: int = 0


class Plc(Device):
    """The line PLC's process handshake."""

    family = "plc"

    def __init__(
        self,
        *,
        timeout_s: float = 2.0,
        heartbeat_timeout_s: float = 3.0,
        poll_s: float = 0.1,
        name: str = "",
    ) -> None:
        super().__init__(timeout_s=timeout_s, name=name)
        if not (heartbeat_timeout_s > 0 and poll_s > 0):
            raise DeviceConfigError("heartbeat_timeout_s and poll_s must be > 0")
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self.poll_s = float(poll_s)
        self._out = PlcOutputs()
        self._last_beat: tuple[int, float] | None = None

    @property
    def outputs(self) -> PlcOutputs:
        return self._out

    def poll(self) -> PlcInputs:
        """Read the inputs and send our heartbeat (one exchange)."""
        inputs = self._read_retrying(self._read_inputs)
        now = time.monotonic()
        if self._last_beat is None or self._last_beat[0] != inputs.heartbeat:
            self._last_beat = (inputs.heartbeat, now)
        self._send(replace(self._out, heartbeat=(self._out.heartbeat + 1) & 0xFFFF))
        return inputs

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
        self._read_retrying(lambda: self._write_outputs(outputs))  # idempotent: a register image
        self._out = outputs

    def _open_handshake(self) -> None:
        """Reset the outputs on connect: not busy, not done, no fault."""
        self._out = PlcOutputs()
        self._last_beat = None

    @abstractmethod
    def _read_inputs(self) -> PlcInputs: ...

    @abstractmethod
    def _write_outputs(self, outputs: PlcOutputs) -> None: ...
