"""Time as the service sees it: a `Clock` (monotonic and wall time, sleep, wait on an event).

Everything in app/line takes its time from a Clock, never from `time` directly, so the simulated
line can run the service at a time scale (its ScaledClock has the same duck type). All values
are in the clock's own seconds (simulated seconds for a scaled clock).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float:
        """Seconds of a clock that never goes back."""
        ...

    def time(self) -> float:
        """Wall-clock time, seconds since the epoch (for timestamps)."""
        ...

    def sleep(self, s: float) -> None:
        """Sleep `s` seconds of this clock."""
        ...

    def wait(self, event: threading.Event, s: float) -> bool:
        """Wait up to `s` seconds of this clock for `event`; True if it is set."""
        ...


class RealClock:
    """The machine's clocks."""

    def monotonic(self) -> float:
        return time.monotonic()

    def time(self) -> float:
        return time.time()

    def sleep(self, s: float) -> None:
        time.sleep(max(0.0, s))

    def wait(self, event: threading.Event, s: float) -> bool:
        return event.wait(max(0.0, s))
