"""Shared by the TUI tests: waiting on the screen's state in a bounded loop (never a bare
sleep), and skipping the simulated line's idle time between clamp windows."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

from textual.pilot import Pilot
from textual.widgets import Static

from app.sim.line_run import SimulatedLineRun
from app.tui.app import RvisTui
from app.tui.modals import ConfirmScreen
from fakes.clock import VirtualClock


async def until(pilot: Pilot[None], cond: Callable[[], bool], timeout_s: float = 15.0) -> None:
    """Let the app run until cond() holds; AssertionError (with the screen's status line and
    banner) after timeout_s."""
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            app = pilot.app
            assert isinstance(app, RvisTui)
            shown = f"{text_of(app, '#status')!r} {text_of(app, '#banner')!r}"
            workers = [(w.name, w.state.name, repr(w.error)) for w in app.workers]
            raise AssertionError(
                f"condition not met in {timeout_s:g} s; screen: {shown}; pane {app.pane}, "
                f"workers {workers}"
            )
        await pilot.pause(0.05)


async def press(pilot: Pilot[None], *keys: str) -> None:
    """Press keys, each handled before the next. Pilot.press also waits for the process to
    go idle (up to 2 s a key), which never happens with a service running in this process."""
    for key in keys:
        pilot.app.simulate_key(key)
        await pilot.pause(0.02)


async def confirm(pilot: Pilot[None], key: str) -> None:
    """Press the key of an action that asks first, and answer yes."""
    await press(pilot, key)
    await until(pilot, lambda: isinstance(pilot.app.screen, ConfirmScreen))
    await press(pilot, "y")
    await until(pilot, lambda: not isinstance(pilot.app.screen, ConfirmScreen))


def text_of(app: RvisTui, selector: str) -> str:
    return str(app.query_one(selector, Static).render())


SKIP_TIMEOUT_S = 30.0  # [real s] for the service's next wait to make the jump


class IdleSkipper:
    """While inside (`with IdleSkipper(run):`), each time the service becomes idle (after a
    window, a reset, at the start), the line's clock jumps to `lead_s` sim seconds before the
    next window opens: only time in which the service waits for a window passes at once; a
    window itself runs at the line's own pace. `between_windows(fn)` runs fn once, right after
    such a jump (the service idle, the next window not yet open)."""

    def __init__(self, run: SimulatedLineRun, lead_s: float = 1.0) -> None:
        self.run, self.lead_s = run, lead_s
        self._events = run.service.bus.subscribe()
        self._calls: queue.SimpleQueue[tuple[Callable[[], object], threading.Event]]
        self._calls = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._follow, name="idle-skipper", daemon=True)

    def __enter__(self) -> IdleSkipper:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._events.put({"event": "end"})  # wakes the follower, which returns
        self._thread.join()
        self.run.service.bus.unsubscribe(self._events)

    def between_windows(self, fn: Callable[[], object]) -> threading.Event:
        """Run fn after the next jump; the event is set once it has run."""
        done = threading.Event()
        self._calls.put((fn, done))
        return done

    def _follow(self) -> None:
        while (event := self._events.get())["event"] != "end":
            if event["event"] == "state" and event.get("to") == "idle" and self._skip():
                while not self._calls.empty():
                    fn, done = self._calls.get()
                    fn()
                    done.set()

    def _skip(self) -> bool:
        """Jump to lead_s before the next window, if the service is idle (True if it was). The
        jump of a VirtualClock is made by the thread that makes the line's time pass (a callback
        due now, run at the service's next wait): one thread passes time at a time."""
        clock = self.run.line.clock
        if not isinstance(clock, VirtualClock):  # a ScaledClock's jump wakes its sleepers
            return self._jump()
        done = threading.Event()
        jumped: list[bool] = []

        def jump() -> None:
            try:
                jumped.append(self._jump())
            finally:
                done.set()

        clock.call_at(clock.monotonic(), jump)
        return done.wait(SKIP_TIMEOUT_S) and jumped == [True]

    def _jump(self) -> bool:
        line = self.run.line
        now_s, period_s = line.clock.monotonic(), line.settings.period_s
        k = int(now_s // period_s)
        opens_s = line.window_bounds_s(k)[0]
        if opens_s - self.lead_s <= now_s:  # this cycle's window is open or about to: the next
            opens_s = line.window_bounds_s(k + 1)[0]
        if self.run.service.state.value != "idle":
            return False
        line.clock.advance(opens_s - self.lead_s - now_s)
        return True


def poll_screen(check: Callable[[], bool], timeout_s: float) -> bool:
    """check() until true or timeout_s (tmux offers no event on screen content: poll it)."""
    tick, deadline = threading.Event(), time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            return False
        tick.wait(0.1)
    return True
