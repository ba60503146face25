"""Time as the service and the simulated cell's peers see it: a `Clock` (monotonic and wall
time, sleep, wait on an event), all in the clock's own seconds.

Everything in app/line takes its time from a Clock, never from `time` directly, so the
simulated line can run the service in its own time: virtual time (fakes.clock.VirtualClock),
which moves only by the simulated durations of what happens, or a wall clock at a time scale
(fakes.clock.ScaledClock). `RealClock` is the machine's (scale 1).

A clock whose time moves only when a caller makes it pass is a `TimerClock`: `sleep` and `wait`
make their sim seconds pass (they are the waits of the one actor that drives time, the
service's loop), and a watcher that must act at a sim time while something else makes time
pass (the window watch while the robot moves) registers a callback with `call_at`, run at that
sim time by whoever is making time pass then.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """What the service and the peers need of time (all in sim seconds)."""

    def monotonic(self) -> float: ...

    def time(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...

    def wait(self, event: threading.Event, seconds: float) -> bool: ...


@runtime_checkable
class SimClock(Clock, Protocol):
    """A Clock that also says how many sim seconds pass per real second."""

    @property
    def scale(self) -> float: ...


class Timer(Protocol):
    """A callback registered with `TimerClock.call_at`."""

    def cancel(self) -> None:
        """It will not run (if it has not run yet)."""
        ...


@runtime_checkable
class TimerClock(Clock, Protocol):
    """A Clock whose time moves only when a caller makes it pass (module docstring)."""

    def call_at(self, t: float, fn: Callable[[], None]) -> Timer:
        """Run `fn()` when the clock passes monotonic time `t` (a time already passed: the next
        time it moves)."""
        ...


class RealClock:
    """Wall-clock time (scale 1)."""

    scale = 1.0

    def monotonic(self) -> float:
        return time.monotonic()

    def time(self) -> float:
        return time.time()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(seconds, 0.0))

    def wait(self, event: threading.Event, seconds: float) -> bool:
        return event.wait(max(seconds, 0.0))
