"""The line's clocks. VirtualClock: time stands until something makes it pass, passes exactly
the sim seconds asked, runs callbacks at their sim times in the thread making it pass, stops
where a stop event was set; paced, it waits for the wall clock without changing what happens.
ScaledClock: sim time runs `scale` times faster than real time, waits and sleeps are in sim
seconds, `advance` jumps ahead and wakes sleepers, a clock built stopped stands at 0."""

from __future__ import annotations

import threading
import time

import pytest

from fakes.clock import (
    Clock,
    ConcurrentMover,
    RealClock,
    ScaledClock,
    SimClock,
    TimerClock,
    VirtualClock,
)


def test_the_clocks_satisfy_the_protocol() -> None:
    for clock in (RealClock(), ScaledClock(10.0), VirtualClock(), VirtualClock(pace=10.0)):
        assert isinstance(clock, Clock) and isinstance(clock, SimClock)
    assert isinstance(VirtualClock(), TimerClock)
    assert not isinstance(ScaledClock(10.0), TimerClock) and not isinstance(RealClock(), TimerClock)


def test_virtual_time_stands_until_made_to_pass_and_passes_exactly() -> None:
    clock = VirtualClock(start_epoch=1_000_000.0)
    assert clock.monotonic() == 0.0 and clock.time() == 1_000_000.0
    assert clock.scale == float("inf")  # as fast as the CPU
    time.sleep(0.05)  # sleep-ok: real time passes, not sim time
    assert clock.monotonic() == 0.0
    assert clock.elapse(2.5) == 2.5
    clock.sleep(0.25)  # sleep-ok: the driving actor's wait, under test (no real time)
    assert clock.monotonic() == 2.75 and clock.passed_s == 2.75
    event = threading.Event()
    assert clock.wait(event, 1.0) is False and clock.monotonic() == 3.75
    event.set()
    assert clock.wait(event, 3600.0) is True and clock.monotonic() == 3.75  # set: no time
    clock.advance(100.0)  # a jump, not a simulated duration
    assert clock.monotonic() == 103.75 and clock.passed_s == 3.75
    with pytest.raises(ValueError):
        clock.advance(-1.0)


def test_callbacks_run_at_their_sim_times_in_the_thread_making_time_pass() -> None:
    clock = VirtualClock()
    seen: list[tuple[str, float, str]] = []

    def note(name: str) -> None:
        seen.append((name, clock.monotonic(), threading.current_thread().name))

    clock.call_at(3.0, lambda: note("c"))
    clock.call_at(1.0, lambda: note("a"))
    clock.call_at(1.0, lambda: note("b"))  # same time: in the order registered
    clock.call_at(2.0, lambda: note("never")).cancel()
    clock.call_at(10.0, lambda: note("later"))
    mover = threading.Thread(target=clock.elapse, args=(5.0,), name="mover")
    mover.start()
    mover.join(5.0)
    assert seen == [("a", 1.0, "mover"), ("b", 1.0, "mover"), ("c", 3.0, "mover")]
    assert clock.monotonic() == 5.0
    clock.call_at(4.0, lambda: note("past"))  # already passed: the next time it moves
    clock.elapse(0.0)
    assert seen[-1] == ("past", 5.0, "MainThread")
    clock.advance(5.0)  # a jump runs what is due on the way too
    assert seen[-1] == ("later", 10.0, "MainThread")


def test_a_callback_that_stops_the_passing_time_leaves_it_at_its_own() -> None:
    clock = VirtualClock()
    stop = threading.Event()
    clock.call_at(0.4, lambda: None)
    clock.call_at(1.5, stop.set)  # e.g. an abort sent from the window watch
    assert clock.elapse(4.0, stop) == 1.5
    assert clock.monotonic() == 1.5


def test_a_paced_clock_waits_for_the_wall_clock_and_jumps_do_not() -> None:
    clock = VirtualClock(pace=50.0)
    clock.start()
    r0 = time.monotonic()
    clock.elapse(10.0)  # 10 sim s = 0.2 real s
    # (the upper bounds on the wall time tell the behaviour from the other one by a wide
    # margin, so that a loaded machine's delays cannot fail them: the pace is the lower bound)
    assert 0.2 <= time.monotonic() - r0 < 2.0
    assert clock.monotonic() == 10.0  # exactly, whatever the machine's load
    r0 = time.monotonic()
    clock.advance(3600.0)
    assert time.monotonic() - r0 < 7.2 and clock.monotonic() == 3610.0  # paced: 72 s
    event = threading.Event()
    threading.Timer(0.05, event.set).start()  # an operator's command, 2.5 sim s in
    r0 = time.monotonic()
    assert clock.wait(event, 600.0) is True
    assert time.monotonic() - r0 < 6.0  # the whole wait: 12 s
    assert 3610.0 < clock.monotonic() < 3610.0 + 600.0
    with pytest.raises(ValueError):
        VirtualClock(pace=0.0)


def test_sim_time_runs_at_the_scale() -> None:
    clock = ScaledClock(50.0, start_epoch=1_000_000.0)
    # each sim reading between two real ones: the scale checked within what the readings
    # bracket, however long the machine keeps this thread from running between them
    r0, s0, r0_after = time.monotonic(), clock.monotonic(), time.monotonic()
    clock.sleep(10.0)  # sleep-ok: the clock's own sleep under test (10 sim s = 0.2 real s)
    r1_before, s1, r1 = time.monotonic(), clock.monotonic(), time.monotonic()
    sim = s1 - s0
    assert sim >= 10.0
    assert 50.0 * (r1_before - r0_after) * 0.999 <= sim <= 50.0 * (r1 - r0) * 1.001
    assert 0.2 <= r1 - r0 < 2.0  # (a wide upper bound: a loaded machine wakes a sleeper late)
    m0, t, m1 = clock.monotonic(), clock.time(), clock.monotonic()
    assert 1_000_000.0 + m0 <= t <= 1_000_000.0 + m1


def test_wait_returns_the_event_flag_after_sim_seconds() -> None:
    clock = ScaledClock(100.0)
    event = threading.Event()
    r0 = time.monotonic()
    assert clock.wait(event, 20.0) is False  # 20 sim s = 0.2 real s
    assert 0.2 <= time.monotonic() - r0 < 2.0
    event.set()
    r0 = time.monotonic()
    assert clock.wait(event, 3600.0) is True
    assert time.monotonic() - r0 < 3.6  # at once, not after the 36 s


def test_advance_jumps_ahead_and_wakes_a_sleeper() -> None:
    clock = ScaledClock(1.0)
    done = threading.Event()

    def sleep_an_hour() -> None:
        clock.sleep(3600.0)  # sleep-ok: woken by advance(), under test
        done.set()

    sleeper = threading.Thread(target=sleep_an_hour, daemon=True)
    sleeper.start()
    t0 = clock.monotonic()
    clock.advance(3600.0)
    assert done.wait(2.0), "the sleeper did not wake up after advance"
    sleeper.join(1.0)
    assert clock.monotonic() - t0 >= 3600.0
    with pytest.raises(ValueError):
        clock.advance(-1.0)


def test_a_clock_built_stopped_stands_at_zero_until_started() -> None:
    clock = ScaledClock(1000.0, started=False)
    event = threading.Event()
    assert clock.wait(event, 0.0) is False
    assert clock.monotonic() == 0.0
    clock.start()
    clock.sleep(50.0)  # sleep-ok: the stopped clock's sleep under test
    assert clock.monotonic() >= 50.0


def test_bad_scale_is_refused() -> None:
    for scale in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError):
            ScaledClock(scale)


def test_one_thread_passes_time_at_a_time() -> None:
    """A second mover from another thread raises at once, whichever way it would make time
    pass; a callback that makes time pass from within the passing (the same thread) is fine."""
    clock = VirtualClock()
    inside, release = threading.Event(), threading.Event()

    def callback() -> None:  # runs in the mover's thread, at sim time 1.0
        inside.set()
        assert release.wait(10)
        assert clock.elapse(0.5) == 0.5  # re-entry from the same thread

    clock.call_at(1.0, callback)
    first = threading.Thread(target=clock.elapse, args=(2.0,), name="first")
    first.start()
    assert inside.wait(10)
    second_moves = (
        lambda: clock.elapse(1.0),
        lambda: clock.sleep(1.0),  # sleep-ok: a second mover's wait, refused
        lambda: clock.wait(threading.Event(), 1.0),
        lambda: clock.advance(1.0),
    )
    for move in second_moves:
        with pytest.raises(ConcurrentMover, match="'first'"):
            move()
    release.set()
    first.join(10)
    assert not first.is_alive()
    assert clock.monotonic() == 2.0 and clock.passed_s == 2.0  # the inner 0.5 s within the 2 s
    assert clock.elapse(1.0) == 1.0  # the first is done: another thread may move now


def test_a_paced_wait_holds_no_lock() -> None:
    """While a paced clock waits for the wall clock, the other threads read it, register
    callbacks and are refused as movers at once (none waits for the paced mover)."""
    clock = VirtualClock(pace=1.0)  # 1 sim s per real s: the mover waits 60 real s...
    stop, begun = threading.Event(), threading.Event()
    clock.call_at(0.0, begun.set)  # run by the mover as its passing begins
    first = threading.Thread(target=clock.elapse, args=(60.0, stop), name="paced")
    first.start()
    refused = threading.Event()

    def second() -> None:
        clock.call_at(100.0, lambda: None)
        assert clock.monotonic() < 60.0
        try:
            clock.elapse(1.0)
        except ConcurrentMover:
            refused.set()

    other = threading.Thread(target=second, name="second")
    assert begun.wait(10)
    other.start()
    assert refused.wait(10)  # ...and the second is refused long before
    stop.set()  # ...unless stopped
    first.join(10)
    assert not first.is_alive() and clock.monotonic() < 60.0


def test_a_clock_that_is_not_strict_makes_a_second_mover_wait_its_turn() -> None:
    """strict=False (the rendered line's peers): the second mover waits, holding nothing, and
    passes its time once the first is done."""
    clock = VirtualClock(strict=False)
    inside, release = threading.Event(), threading.Event()

    def hold() -> None:  # the first mover's callback at sim time 1.0
        inside.set()
        assert release.wait(10)

    clock.call_at(1.0, hold)
    first = threading.Thread(target=clock.elapse, args=(2.0,), name="first")
    first.start()
    assert inside.wait(10)
    done = threading.Event()

    def second_mover() -> None:
        clock.elapse(0.5)
        done.set()

    second = threading.Thread(target=second_mover, name="second")
    second.start()
    assert clock.monotonic() == 1.0 and not done.is_set()  # the first holds the turn
    assert clock.wait_turns(1, timeout_s=10)  # the second waits for its turn (counted)
    assert clock.turns_waited == 1 and not done.is_set()
    release.set()
    assert done.wait(10)
    first.join(10)
    second.join(10)
    assert clock.monotonic() == 2.5 and clock.passed_s == 2.5
