"""FANUC robot through a register mailbox over Modbus TCP: ``modbus://host:502?unit=1&base=0``.

For controllers without RMI: the controller's Modbus TCP server option exposes R[] registers as
holding registers, and the TP program RVIS_MBX (docs/fanuc-modbus-mailbox.md, listing
docs/RVIS_MBX.ls) serves the mailbox: it waits for a new command counter, moves, and acknowledges.
Every R[] is a REAL in two words (low word first). Word offsets from ``base``:

    R[1]  0  CMD      command counter (app)      R[11] 20  ACK      counter accepted (TP)
    R[2]  2  SPEED    percent (app)              R[12] 22  DONE     counter completed (TP)
    R[3]  4  J1..J6   target [deg] (app, 12 w)   R[13] 24  STATUS   0 idle 1 moving 2 fault (TP)
    R[9]  16 RESET    reset counter (app)        R[14] 26  ERROR    alarm / error code (TP)
    R[10] 18 ABORT    abort counter (app)        R[15] 28  J1..J6   current [deg] (TP, 12 w)
                                                 R[21] 40  BEAT     heartbeat (TP)

A move: write SPEED and the target, then CMD+1 (a second request, so the TP never sees a
counter before its data), then poll until DONE == CMD (or STATUS == 2: DeviceFault with ERROR).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers._modbus import (
    ModbusLink,
    WordOrder,
    floats_to_words,
    require_link,
    words_to_floats,
)
from drivers.errors import DeviceFault, DeviceTimeout
from drivers.robot import FloatArray, Robot, RobotStatus
from drivers.safety import SafetyGuard
from drivers.url import DeviceUrl

DEFAULT_PORT = 502
STATUS_IDLE, STATUS_MOVING, STATUS_FAULT = 0, 1, 2
COUNTER_WRAP = 10_000  # counters stay small, exact integers in a REAL


@dataclass(frozen=True)
class Mailbox:
    """Word offsets of the mailbox registers (relative to ``base``)."""

    CMD: int = 0
    SPEED: int = 2
    TARGET: int = 4
    RESET: int = 16
    ABORT: int = 18
    ACK: int = 20
    DONE: int = 22
    STATUS: int = 24
    ERROR: int = 26
    CURRENT: int = 28
    BEAT: int = 40
    SIZE: int = 42


MAILBOX = Mailbox()


class ModbusRobot(Robot):
    """``ModbusRobot("10.0.0.5", 502, unit=1, base=0, guard=...)``; open() connects."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        unit: int = 1,
        base: int = 0,
        word_order: WordOrder = "little",
        poll_s: float = 0.02,
        guard: SafetyGuard | None = None,
        timeout_s: float = 2.0,
        motion_timeout_s: float = 120.0,
        name: str = "",
    ) -> None:
        super().__init__(
            guard=guard,
            timeout_s=timeout_s,
            motion_timeout_s=motion_timeout_s,
            name=name or f"modbus://{host}:{port}",
        )
        self.host, self.port, self.unit, self.base = host, int(port), int(unit), int(base)
        self.word_order: WordOrder = word_order
        self.poll_s = float(poll_s)
        self._link: ModbusLink | None = None
        self._counters = {"CMD": 0, "RESET": 0, "ABORT": 0}
        # abort() writes from another thread between the motion's polls: one request at a time
        self._io = threading.RLock()
        self._aborted = False

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> ModbusRobot:
        host, port = url.address(DEFAULT_PORT)
        options.setdefault("unit", int(url.number("unit", 1)))
        options.setdefault("base", int(url.number("base", 0)))
        return cls(host, port, **options)

    def _open(self) -> None:
        link = ModbusLink(
            self.host, self.port, unit=self.unit, timeout_s=self.timeout_s, trace=self.trace
        )
        link.connect()
        self._link = link
        app = self._floats(MAILBOX.CMD, MAILBOX.ACK)  # continue the counters the TP last saw
        self._counters = {"CMD": int(app[0]), "RESET": int(app[8]), "ABORT": int(app[9])}

    def _close(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            link.close()

    def describe(self) -> str:
        self._check_open()
        return f"FANUC Modbus mailbox at {self.host}:{self.port} unit {self.unit} base {self.base}"

    # -- primitives ---------------------------------------------------------------------------
    def _read_joints(self) -> FloatArray:
        return np.array(self._floats(MAILBOX.CURRENT, 12))

    def _status(self) -> RobotStatus:
        status, error = (int(v) for v in self._floats(MAILBOX.STATUS, 4))
        if self._aborted and status == STATUS_FAULT:  # our own abort, cleared before the next move
            return RobotStatus(servo_ready=True, moving=False, fault=False, detail="aborted")
        return RobotStatus(
            servo_ready=status != STATUS_FAULT,
            moving=status == STATUS_MOVING,
            fault=status == STATUS_FAULT,
            error_code=error,
            detail=f"TP error {error}" if error else "",
        )

    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None:
        if self._aborted:  # the TP program reports an abort as a fault: clear it first
            self._reset()
        self._write_floats(MAILBOX.SPEED, [speed_pct, *q_deg])
        cmd = self._bump("CMD")
        deadline = time.monotonic() + timeout_s
        while True:
            _ack, done, status, error = (int(v) for v in self._floats(MAILBOX.ACK, 8))
            if done == cmd:
                return
            if status == STATUS_FAULT:
                raise DeviceFault(f"{self.name}: TP program fault, error {error}", code=error)
            if time.monotonic() >= deadline:
                self._bump("ABORT")
                raise DeviceTimeout(f"{self.name}: motion {cmd} not done in {timeout_s:g} s")
            time.sleep(self.poll_s)

    def _abort(self) -> None:
        self._bump("ABORT")
        self._aborted = True

    def _reset(self) -> None:
        self._bump("RESET")
        self._aborted = False
        deadline = time.monotonic() + self.timeout_s
        while int(self._floats(MAILBOX.STATUS, 2)[0]) == STATUS_FAULT:
            if time.monotonic() >= deadline:
                raise DeviceTimeout(f"{self.name}: fault not cleared by reset")
            time.sleep(self.poll_s)

    # -- registers ----------------------------------------------------------------------------
    def _bump(self, name: str) -> int:
        with self._io:
            value = self._counters[name] % COUNTER_WRAP + 1
            self._write_floats(getattr(MAILBOX, name), [value])
            self._counters[name] = value
        return value

    def _floats(self, offset: int, words: int) -> list[float]:
        with self._io:
            link = require_link(self._link, self.name)
            return words_to_floats(link.read(self.base + offset, words), self.word_order)

    def _write_floats(self, offset: int, values: list[float]) -> None:
        with self._io:
            link = require_link(self._link, self.name)
            link.write(self.base + offset, floats_to_words(values, self.word_order))
