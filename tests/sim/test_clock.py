"""The line's clock: sim time runs `scale` times faster than real time, waits and sleeps are in
sim seconds, `advance` jumps ahead and wakes sleepers, a clock built stopped stands at 0."""

from __future__ import annotations

import threading
import time

import pytest

from fakes.clock import Clock, RealClock, ScaledClock, SimClock


def test_both_clocks_satisfy_the_protocol() -> None:
    for clock in (RealClock(), ScaledClock(10.0)):
        assert isinstance(clock, Clock) and isinstance(clock, SimClock)


def test_sim_time_runs_at_the_scale() -> None:
    clock = ScaledClock(50.0, start_epoch=1_000_000.0)
    r0, s0 = time.monotonic(), clock.monotonic()
    clock.sleep(10.0)  # sleep-ok: the clock's own sleep under test (10 sim s = 0.2 real s)
    real, sim = time.monotonic() - r0, clock.monotonic() - s0
    assert sim >= 10.0
    assert sim == pytest.approx(50.0 * real, rel=0.02)
    assert 0.2 <= real < 0.4
    assert clock.time() == pytest.approx(1_000_000.0 + clock.monotonic(), abs=0.5)


def test_wait_returns_the_event_flag_after_sim_seconds() -> None:
    clock = ScaledClock(100.0)
    event = threading.Event()
    r0 = time.monotonic()
    assert clock.wait(event, 20.0) is False  # 20 sim s = 0.2 real s
    assert 0.2 <= time.monotonic() - r0 < 0.4
    event.set()
    r0 = time.monotonic()
    assert clock.wait(event, 3600.0) is True
    assert time.monotonic() - r0 < 0.05


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
