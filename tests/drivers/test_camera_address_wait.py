"""Simulations side by side (issue 40 item 2): one simulated GigE camera per address, so a second
simulation waits for the first one's camera; it says so at once, in one line naming the address
and the holder, instead of waiting silently; a user's command waits as long as it takes (its
simulation goes on when the other ends), a test's wait is bounded."""

from __future__ import annotations

import os

import pytest

from fakes.gv_camera import _AddressLock

ADDRESS = "127.0.0.9"  # no camera of the suite's: only this test takes its lock


def test_a_second_holder_is_told_at_once_and_goes_on_when_the_first_ends() -> None:
    first, second = _AddressLock(ADDRESS), _AddressLock(ADDRESS)
    first.acquire(0.0)
    told: list[str] = []

    def on_wait(line: str) -> None:
        told.append(line)
        first.release()  # the other simulation ends while this one waits

    try:
        second.acquire(None, on_wait)  # as long as it takes: goes on once the first ends
    finally:
        second.release()
        first.release()
    (line,) = told
    assert ADDRESS in line and f"pid {os.getpid()}" in line and "another simulation" in line


def test_a_bounded_wait_names_the_holder_when_it_gives_up() -> None:
    first, second = _AddressLock(ADDRESS), _AddressLock(ADDRESS)
    first.acquire(0.0)
    told: list[str] = []
    try:
        with pytest.raises(RuntimeError, match=f"pid {os.getpid()}"):
            second.acquire(0.2, told.append)
    finally:
        first.release()
    assert len(told) == 1
