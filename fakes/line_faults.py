"""Device faults of the simulated line, and the PLC peer whose window can be withdrawn.

Each `Fault` is played by the peer the real driver talks to, so the service sees exactly what
the driver raises on hardware:

    plc_heartbeat_loss   the PLC heartbeat freezes (until cleared)   -> DeviceTimeout waiting
    window_withdrawn     the clamp window closes early (this one, or the next one if none is open)
    robot_disconnect     the next motion loses its RMI sessions half-way -> DeviceConnectionError
    controller_alarm     the next motion stops half-way on a controller alarm -> DeviceFault
    camera_timeout       the camera stops streaming (until cleared)  -> DeviceTimeout on grab
    galvo_error          the next voltage command queues a DAC error -> DeviceFault(code -240)

`FaultScheduler` plays faults at chosen sim times on the line's clock: on a VirtualClock as
callbacks at those times (run by whatever makes time pass: a fault lands at the same point of a
run every time), on a ScaledClock from a daemon thread waiting on the clock; closed with the
line.
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass, field
from typing import Any

from drivers.plc import WINDOW_OPEN
from drivers.plc_modbus import PLC_STATUS
from fakes.clock import Clock, TimerClock
from fakes.devices import ClampCycle
from fakes.plc import PlcServer

#: SCPI "Hardware error": what the DAC queues for an injected galvo fault.
GALVO_ERROR_CODE = -240


class Fault(enum.StrEnum):
    PLC_HEARTBEAT_LOSS = "plc_heartbeat_loss"
    WINDOW_WITHDRAWN = "window_withdrawn"
    ROBOT_DISCONNECT = "robot_disconnect"
    CONTROLLER_ALARM = "controller_alarm"
    CAMERA_TIMEOUT = "camera_timeout"
    GALVO_ERROR = "galvo_error"


def window_bounds_s(cycle: ClampCycle, k: int) -> tuple[float, float]:
    """Sim times [s] at which clamp window k (0, 1, ...) opens and closes."""
    end = (k + 1) * cycle.period_s
    return end - cycle.window_s, end


def window_at(cycle: ClampCycle, t_s: float) -> int | None:
    """The index of the clamp window open at sim time t_s, or None between windows."""
    k = int(t_s // cycle.period_s)
    opens, _ = window_bounds_s(cycle, k)
    return k if t_s >= opens else None


class LinePlc(PlcServer):
    """The line PLC (a PlcServer on the line's clock, sim time 0 = the line's start) whose
    current clamp window can be withdrawn early."""

    def __init__(self, cycle: ClampCycle, clock: Clock, **kw: Any) -> None:
        super().__init__(cycle, clock=clock, **kw)
        self._withdrawn_until_s = -1.0

    def start(self) -> LinePlc:
        super().start()
        self.t0 = 0.0  # the clamp cycle runs from the line's sim time 0, not from this start
        return self

    def withdraw_window(self) -> None:
        """Close the window open now at once, or the next one as it would open."""
        now = self.clock.monotonic() - self.t0
        k = window_at(self.cycle, now)
        k = k if k is not None else int(now // self.cycle.period_s)
        self._withdrawn_until_s = window_bounds_s(self.cycle, k)[1]

    def restore_window(self) -> None:
        self._withdrawn_until_s = -1.0

    def scan(self, now: float, regs: list[int], written: dict[int, int]) -> None:
        super().scan(now, regs, written)
        if now - self.t0 < self._withdrawn_until_s:
            regs[self.base + PLC_STATUS] &= ~WINDOW_OPEN


@dataclass(order=True)
class _Planned:
    at_s: float
    fault: Fault = field(compare=False)
    done: threading.Event = field(compare=False, default_factory=threading.Event)


class FaultScheduler:
    """Plays `fault` through `play(fault)` when the line's clock reaches each planned time."""

    def __init__(self, clock: Clock, play: Any) -> None:
        self._clock, self._play = clock, play
        self._planned: list[_Planned] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = False
        self.played: list[tuple[Fault, float]] = []  # (fault, sim time played), in order
        self._thread = threading.Thread(target=self._run, name="line-faults", daemon=True)

    def start(self) -> None:
        if not isinstance(self._clock, TimerClock):
            self._thread.start()

    def close(self) -> None:
        self._stopping = True
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(5.0)

    def plan(self, fault: Fault, at_s: float) -> threading.Event:
        """Play `fault` at sim time at_s; the event is set once it has been played."""
        item = _Planned(float(at_s), Fault(fault))
        if isinstance(self._clock, TimerClock):
            self._clock.call_at(item.at_s, lambda: self._play_now(item))
            return item.done
        with self._lock:
            self._planned.append(item)
            self._planned.sort()
        self._wake.set()
        return item.done

    def _run(self) -> None:
        while not self._stopping:
            with self._lock:
                due = self._planned[0] if self._planned else None
            if due is None:  # nothing planned: sleep until plan() or close(), no polling
                self._wake.wait()
                self._wake.clear()
                continue
            wait_s = due.at_s - self._clock.monotonic()
            if wait_s > 0 and self._clock.wait(self._wake, wait_s):
                self._wake.clear()
                continue
            if self._stopping:
                continue
            with self._lock:
                self._planned.remove(due)
            self._play_now(due)

    def _play_now(self, item: _Planned) -> None:
        if self._stopping:
            return
        self._play(item.fault)
        self.played.append((item.fault, self._clock.monotonic()))
        item.done.set()
