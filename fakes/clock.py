"""Real or simulated time, shared by the simulated line's peers and the service.

The contract is drivers.clock's Clock: ``monotonic()`` [sim s], ``time()`` [sim epoch s],
``sleep(seconds)`` [sim s] and ``wait(event, seconds) -> bool`` (the event's flag, after at
most ``seconds`` sim s); RealClock is drivers.clock's too.

``ScaledClock(scale)`` runs ``scale`` sim seconds per real second (60: one sim minute per real
second) from sim time 0 at construction (or at ``start()``, with ``started=False``: it stands at
0 until then); ``advance(seconds)`` jumps it forward (fast-forward to the interesting part of a
shift in a test). Both clocks carry ``scale``, which the protocol peers
use to turn a sim duration into a real sleep on their event loops.
"""

from __future__ import annotations

import threading
import time

from drivers.clock import Clock, RealClock, SimClock

__all__ = ["Clock", "RealClock", "ScaledClock", "SimClock"]

#: Longest real wait [s] of ``ScaledClock.wait`` between looks at the clock, so that a waiter
#: notices ``advance()``; the event itself still wakes it at once.
_WAIT_CHUNK_REAL_S = 0.1


class ScaledClock:
    """Sim time = real time since construction x ``scale`` (+ any ``advance``).

    start_epoch: the Unix time [s] that sim time 0 stands for (default: now); started=False:
    the clock stands at 0 until ``start()``.
    """

    def __init__(
        self, scale: float, start_epoch: float | None = None, *, started: bool = True
    ) -> None:
        if not (scale > 0 and scale < float("inf")):
            raise ValueError(f"clock scale must be a positive number, got {scale!r}")
        self._scale = float(scale)
        self.start_epoch = time.time() if start_epoch is None else float(start_epoch)
        self._t0_real: float | None = time.monotonic() if started else None
        self._offset_s = 0.0
        self._changed = threading.Condition()

    def start(self) -> None:
        """Let a clock built with started=False run from sim time 0 now (idempotent)."""
        with self._changed:
            if self._t0_real is None:
                self._t0_real = time.monotonic()
                self._changed.notify_all()

    @property
    def scale(self) -> float:
        return self._scale

    def monotonic(self) -> float:
        t0 = self._t0_real
        running_s = 0.0 if t0 is None else time.monotonic() - t0
        return running_s * self._scale + self._offset_s

    def time(self) -> float:
        return self.start_epoch + self.monotonic()

    def real_seconds(self, sim_seconds: float) -> float:
        """How long ``sim_seconds`` of sim time last in real time (ignoring any advance)."""
        return max(sim_seconds, 0.0) / self._scale

    def advance(self, seconds: float) -> None:
        """Jump sim time forward by ``seconds``; sleepers and waiters re-check their deadline."""
        if seconds < 0:
            raise ValueError("a monotonic clock cannot go back")
        with self._changed:
            self._offset_s += seconds
            self._changed.notify_all()

    def sleep(self, seconds: float) -> None:
        deadline = self.monotonic() + seconds
        with self._changed:
            while (left := deadline - self.monotonic()) > 0:
                self._changed.wait(left / self._scale)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        deadline = self.monotonic() + seconds
        while (left := deadline - self.monotonic()) > 0:
            if event.wait(min(left / self._scale, _WAIT_CHUNK_REAL_S)):
                return True
        return event.is_set()
