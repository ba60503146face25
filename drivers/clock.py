"""Time as the service and the simulated cell's peers see it: a `Clock` (monotonic and wall
time, sleep, wait on an event), all in the clock's own seconds.

Everything in app/line takes its time from a Clock, never from `time` directly, so the
simulated line can run the service at a time scale (fakes.clock.ScaledClock: sim seconds,
`scale` of them per real second). `RealClock` is the machine's (scale 1).
"""

from __future__ import annotations

import threading
import time
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
