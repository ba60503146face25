"""Real or simulated time, shared by the simulated line's peers and the service.

The contract is drivers.clock's Clock: ``monotonic()`` [sim s], ``time()`` [sim epoch s],
``sleep(seconds)`` [sim s] and ``wait(event, seconds) -> bool`` (the event's flag, after at
most ``seconds`` sim s); RealClock is drivers.clock's too.

``VirtualClock()``: the simulated line's time. It moves only when something makes it pass: the
service's own waits (``sleep``, ``wait``: its loop is the one actor that drives time) and the
durations the peers charge for what they simulate (``elapse``: a robot motion at its speeds, a
camera exposure and read-out, the DAC's settling, a geometric sweep). Every other thread only
reads it, or registers a callback with ``call_at`` that runs at its sim time in the thread
that makes time pass then (the window watch, the fault scheduler). One thread passes time at a
time, and that is enforced: a thread that would make time pass while another one is doing so
gets ``ConcurrentMover`` (a callback that makes time pass from within the passing, in the same
thread, is fine). No lock is held while a paced clock waits for the wall clock. The rendered
line's clock is not strict (``strict=False``): its fake camera charges each frame from Aravis's
thread and the DAC's server thread the mirror's settling, and a second mover would wait for its
turn (``turns_waited`` counts such waits) instead of failing. None comes on a sweep: the service
waits for the DAC's answer, then for the frame, so the turns come in the program's order. So the
outcome of a run, geometric or rendered, depends on the seed and the settings alone, not on how
fast the machine computed (the rendered one as long as no driver's timeout, kept in real
seconds, runs out: docs/simulated-line.md "Time"). With ``pace=`` (sim s per real s) each
passing also waits for the wall clock, for a person who watches; what happens is the same, only
later (a machine too slow for the pace lags behind).

``ScaledClock(scale)`` runs ``scale`` sim seconds per real second (60: one sim minute per real
second) from sim time 0 at construction (or at ``start()``, with ``started=False``: it stands at
0 until then): time follows the wall clock, so what fits in a window depends on how fast the
machine computes (peers driven by hand in tests and benches). Both clocks carry ``scale``, and
``advance(seconds)`` jumps them forward (fast-forward to the interesting part of a shift).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from drivers.clock import Clock, RealClock, SimClock, TimerClock

__all__ = [
    "Clock",
    "ConcurrentMover",
    "RealClock",
    "ScaledClock",
    "SimClock",
    "TimerClock",
    "VirtualClock",
]

#: Longest real wait [s] of ``ScaledClock.wait`` between looks at the clock, so that a waiter
#: notices ``advance()``; the event itself still wakes it at once.
_WAIT_CHUNK_REAL_S = 0.1

#: A paced VirtualClock that falls more than this behind the wall clock [real s] (a machine too
#: slow for the pace) starts pacing again from where it is instead of catching up in a burst.
_MAX_LAG_REAL_S = 0.5


class ConcurrentMover(RuntimeError):
    """A second thread tried to make a VirtualClock's time pass while another one does."""


@dataclass(order=True)
class _Timer:
    at: float
    seq: int
    fn: Callable[[], None] = field(compare=False)
    cancelled: bool = field(default=False, compare=False)

    def cancel(self) -> None:
        self.cancelled = True


class VirtualClock:
    """Sim time that moves only when something makes it pass (module docstring).

    start_epoch: the Unix time [s] that sim time 0 stands for (default: now, to the whole
    second, so that sim epoch times less the epoch are the same numbers in every run);
    pace: sim seconds per real second while time passes (None: as fast as the CPU);
    strict: a thread that would make time pass while another one does gets ConcurrentMover
    (False: it waits for its turn, holding no lock meanwhile: for a line whose peers charge
    durations from threads of their own at the same time, the rendered line's camera and
    DAC)."""

    def __init__(
        self, start_epoch: float | None = None, *, pace: float | None = None, strict: bool = True
    ) -> None:
        if pace is not None and not (pace > 0 and pace < math.inf):
            raise ValueError(f"clock pace must be a positive number, got {pace!r}")
        self.start_epoch = float(int(time.time())) if start_epoch is None else float(start_epoch)
        self.pace = None if pace is None else float(pace)
        self._now = 0.0
        self.strict = strict
        self._turn = threading.Condition()  # guards the two below (held for no wait)
        self._owner: threading.Thread | None = None  # the thread passing time now
        self._depth = 0  # its passings, one inside another (a callback that passes time)
        self._timers_lock = threading.Lock()
        self._timers: list[_Timer] = []
        self._seq = itertools.count()
        self._anchor: tuple[float, float] | None = None  # pacing: (real s, sim s) in step
        self.passed_s = 0.0  # sim seconds made to pass by elapse/sleep/wait (not advance)
        # passings that waited for another thread's turn (not strict): 0 when every passing
        # came after the one before it ended, as on the rendered line's sweeps (the service
        # waits for the DAC's answer, then for the frame), so their order is the program's
        self.turns_waited = 0

    @property
    def scale(self) -> float:
        """Sim seconds per real second: the pace, or infinity (as fast as the CPU)."""
        return math.inf if self.pace is None else self.pace

    def start(self) -> None:
        """Start pacing from now (a paced clock; idempotent). Time itself stands until
        something makes it pass."""
        with self._moving():
            if self._anchor is None:
                self._anchor = (time.monotonic(), self._now)

    def monotonic(self) -> float:
        return self._now

    def time(self) -> float:
        return self.start_epoch + self._now

    @contextlib.contextmanager
    def _moving(self) -> Iterator[None]:
        """This thread passes time (again, when it already does); when another thread does,
        ConcurrentMover (strict) or a wait for its turn (no lock held while waiting)."""
        me = threading.current_thread()
        with self._turn:
            if self._owner is not None and self._owner is not me and self.strict:
                raise ConcurrentMover(
                    f"thread {me.name!r} cannot make time pass: thread {self._owner.name!r} is "
                    "making it pass (one thread at a time)"
                )
            if self._owner is not None and self._owner is not me:
                self.turns_waited += 1
                self._turn.notify_all()  # `wait_turns`' waiters see the count
            while self._owner is not None and self._owner is not me:
                self._turn.wait()
            self._owner = me
            self._depth += 1
        try:
            yield
        finally:
            with self._turn:
                self._depth -= 1
                if self._depth == 0:
                    self._owner = None
                    self._turn.notify_all()

    def wait_turns(self, n: int, timeout_s: float) -> bool:
        """Wait (real time) until `turns_waited` is at least n; whether it is."""
        with self._turn:
            return self._turn.wait_for(lambda: self.turns_waited >= n, timeout_s)

    # -- callbacks at a sim time --------------------------------------------------------------
    def call_at(self, t: float, fn: Callable[[], None]) -> _Timer:
        """Run `fn()` when time passes `t`, in the thread making it pass (a time already
        passed: the next time it moves). Callbacks at the same time run in the order
        registered; a callback must not wait for the thread that is making time pass."""
        timer = _Timer(float(t), next(self._seq), fn)
        with self._timers_lock:
            heapq.heappush(self._timers, timer)
        return timer

    def _due(self, until: float) -> _Timer | None:
        """The next callback due by `until` (removed from the queue), or None."""
        with self._timers_lock:
            while self._timers and self._timers[0].cancelled:
                heapq.heappop(self._timers)
            if self._timers and self._timers[0].at <= until:
                return heapq.heappop(self._timers)
        return None

    # -- making time pass ---------------------------------------------------------------------
    def elapse(self, seconds: float, stop: threading.Event | None = None) -> float:
        """Let `seconds` of sim time pass (a simulated duration), running the callbacks due on
        the way at their times; paced, also wait for the wall clock. Stops early when `stop`
        is set (looked at before each callback, and at once while pacing). Returns the sim
        seconds that passed."""
        with self._moving():
            t0 = self._now
            self._pass(t0 + max(float(seconds), 0.0), stop, paced=True)
            if self._depth == 1:  # a passing inside this one is part of it
                self.passed_s += self._now - t0
            return self._now - t0

    def advance(self, seconds: float) -> None:
        """Jump sim time forward by `seconds` (tests; the TUI's start into a shift), running
        the callbacks due on the way; paced, without waiting for the wall clock."""
        if seconds < 0:
            raise ValueError("a monotonic clock cannot go back")
        with self._moving():
            self._pass(self._now + seconds, None, paced=False)
            if self._anchor is not None:
                self._anchor = (time.monotonic(), self._now)

    def sleep(self, seconds: float) -> None:
        """The driving actor's wait: `seconds` of sim time pass."""
        self.elapse(seconds)

    def wait(self, event: threading.Event, seconds: float) -> bool:
        """The driving actor's wait on an event: True at once if it is set, else `seconds` of
        sim time pass (less when it is set meanwhile) and its flag is returned."""
        if event.is_set():
            return True
        self.elapse(seconds, stop=event)
        return event.is_set()

    def _pass(self, end: float, stop: threading.Event | None, *, paced: bool) -> None:
        while stop is None or not stop.is_set():
            timer = self._due(end)
            t = end if timer is None else max(timer.at, self._now)
            if paced and self.pace is not None and not self._pace_to(t, stop):
                return
            self._now = max(self._now, t)
            if timer is None:
                return
            timer.fn()

    def _pace_to(self, t: float, stop: threading.Event | None) -> bool:
        """Wait until the wall clock reaches sim time t at the pace; False when `stop` was set
        meanwhile (sim time is then where the wall clock had brought it)."""
        assert self.pace is not None
        if self._anchor is None:
            self._anchor = (time.monotonic(), self._now)
        real0, sim0 = self._anchor
        delay = real0 + (t - sim0) / self.pace - time.monotonic()
        if delay < -_MAX_LAG_REAL_S:
            self._anchor = (time.monotonic(), t)  # fallen behind: pace on from here
        elif delay > 0:
            if stop is None:
                time.sleep(delay)  # sleep-ok: the pace a person watches at
            elif stop.wait(delay):
                reached = sim0 + (time.monotonic() - real0) * self.pace
                self._now = min(max(self._now, reached), t)
                return False
        return True


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
