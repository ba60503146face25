"""One clamp window (README "Line PLC" handshake):

    wait for a fresh window (window bit rising, line running, PLC heartbeat alive)
    -> pick the next schedule slot that fits the remaining window -> busy
    -> move -> sweep + grabs -> vision -> store (committed) -> home -> done

While the robot is out, a watcher polls the PLC; if the window is withdrawn (or the line stops,
or the heartbeat is lost) it aborts the motion at once and the robot goes home: busy drops
without done. A sweep the vision rejects is stored as rejected and the window still ends with
done. A device error propagates (the service goes to FAULT); so does nothing else.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from app.config.line import LineSettings
from app.line.measure import Reading, Rejected, SphereMeasurer
from app.line.schedule import Schedule, Slot
from drivers.clock import Clock, Timer, TimerClock
from drivers.errors import DeviceError
from drivers.plc import BodyId, Plc, PlcInputs

#: record(slot, window, reading or None, reason) -> stored row id; must commit before returning
Recorder = Callable[[Slot, int, Reading | None, str], int]


def cell_temperature(inputs: PlcInputs | None, line: LineSettings) -> tuple[float | None, str]:
    """The cell temperature to use: (degC, "") or (None, why there is none).

    Read only when the cell file says the PLC provides it (`[line] plc_temperature`): a PLC
    program that predates the word leaves 0 there, which must not read as a cell at 0 degC.
    Provided, the word's "no sensor" (0x8000, or a backend without the word) and a value
    outside `plc_temp_min_c..plc_temp_max_c` are no temperature, with the reason."""
    if not line.plc_temperature or inputs is None:
        return None, ""
    temp_c = inputs.temp_c
    if temp_c is None:
        return None, "the PLC's cell temperature word (2) says no sensor (0x8000)"
    lo, hi = line.plc_temp_min_c, line.plc_temp_max_c
    if not lo <= temp_c <= hi:
        return None, (
            f"the PLC's cell temperature word (2) reads {temp_c:.2f} degC, outside [line]"
            f" plc_temp_min_c..plc_temp_max_c = {lo:g}..{hi:g}"
        )
    return temp_c, ""


class WindowWatch:
    """The PLC inputs seen through the service's clock: heartbeat age, window edges, and the
    body clamped in each window (`[line] plc_body_id`): at every rising edge of the window bit
    (and a window open at the first reading) the PLC's body id is read and queued in `clamped`
    as (clock time, body id or None) for the service to store."""

    def __init__(self, plc: Plc, clock: Clock, line: LineSettings) -> None:
        self.plc, self.clock, self.line = plc, clock, line
        self.inputs: PlcInputs | None = None
        self.clamped: deque[tuple[float, BodyId | None]] = deque()
        self._beat: int | None = None
        self._beat_t = 0.0
        self._changed = False
        self._seen_closed = False
        self.opened_t: float | None = None  # clock time of the window's rising edge
        self.used_t: float | None = None  # rising edge of the last window measured in
        # the body's bit (body_ready): its rising edge, the last one measured, the body id
        self._body_seen_low = False
        self.body_opened_t: float | None = None
        self.body_used_t: float | None = None
        self.body_id: BodyId | None = None
        #: the last exchange with the PLC was answered (False before the first and after one
        #: that failed: `inputs` are then the last ones read, not the line's now)
        self.answered = False

    def poll(self) -> PlcInputs:
        """One exchange with the PLC (sends our heartbeat too)."""
        try:
            inputs = self.plc.poll()
        except DeviceError:
            self.answered = False
            raise
        self.answered = True
        now = self.clock.monotonic()
        was_open = self.inputs is not None and self.inputs.window_open
        if inputs.window_open and not was_open and self.line.plc_body_id != "none":
            body = self.plc.read_body_id(self.line.plc_body_id)
            self.clamped.append((self.clock.time(), body))
        self._watch_body(inputs, now)
        if inputs.heartbeat != self._beat:
            self._changed = self._beat is not None  # the first value read is not a beat
            self._beat, self._beat_t = inputs.heartbeat, now
        if not inputs.window_open:
            self._seen_closed, self.opened_t = True, None
        elif self._seen_closed and self.opened_t is None:
            self.opened_t = now  # a window seen from its start: its remaining time is known
        self.inputs = inputs
        return inputs

    def _watch_body(self, inputs: PlcInputs, now: float) -> None:
        """The body_ready bit's rising edge (seen from its start: the body's time is known),
        with the body id read then."""
        was = self.inputs is not None and self.inputs.body_ready
        if not inputs.body_ready:
            self._body_seen_low, self.body_opened_t = True, None
        elif not was and self._body_seen_low:
            self.body_opened_t = now
            fmt = self.line.plc_body_id
            self.body_id = self.plc.read_body_id(fmt) if fmt != "none" else None

    def fresh_body(self) -> bool:
        """A body ready (line running, heartbeat alive), seen from its rising edge, and not
        measured yet."""
        i = self.inputs
        ready = i is not None and i.body_ready and i.line_running and self.alive
        return ready and self.body_opened_t is not None and self.body_opened_t != self.body_used_t

    def body_ready(self) -> bool:
        """The body is still there for the robot (the withdrawal's test while measuring it)."""
        i = self.inputs
        return i is not None and i.body_ready and i.line_running and self.alive

    def body_end_t(self) -> float:
        """The clock's monotonic time the body's window ends ([line] body_window_s)."""
        return (self.body_opened_t or 0.0) + self.line.body_window_s

    @property
    def lost(self) -> bool:
        """No beat for longer than the timeout (counted from the first reading)."""
        age = self.clock.monotonic() - self._beat_t
        return self._beat is not None and age > self.line.heartbeat_timeout_s

    @property
    def alive(self) -> bool:
        """A beat seen within the timeout."""
        age = self.clock.monotonic() - self._beat_t
        return self._changed and age <= self.line.heartbeat_timeout_s

    def ready(self) -> bool:
        i = self.inputs
        return i is not None and i.window_open and i.line_running and self.alive

    def fresh_window(self) -> bool:
        """Ready, seen from its rising edge, and not measured in yet."""
        return self.ready() and self.opened_t is not None and self.opened_t != self.used_t

    def remaining_s(self) -> float:
        if self.opened_t is None:
            return 0.0
        return self.line.window_s - (self.clock.monotonic() - self.opened_t)

    def temperature(self) -> tuple[float | None, str]:
        """The cell temperature of the last reading (cell_temperature)."""
        return cell_temperature(self.inputs, self.line)


class Withdrawal:
    """Watches the PLC while the robot is out, every `poll_s`; on a withdrawn window it aborts
    the robot once and latches `withdrawn` (with `why`). From a thread waiting on the clock; on
    a TimerClock (virtual time, which the robot's motion makes pass) from callbacks at the poll
    times instead, so that it looks at the PLC at the same sim times in every run."""

    def __init__(
        self,
        watch: WindowWatch,
        abort: Callable[[], None],
        ready: Callable[[], bool] | None = None,
    ) -> None:
        """ready: whether the robot may go on (default: the window is there, `watch.ready`;
        a body's measurement: `watch.body_ready`)."""
        self.watch, self._abort = watch, abort
        self._ready = ready or watch.ready
        self.withdrawn = False
        self.why = ""
        self.error: BaseException | None = None
        self._stop = threading.Event()
        clock = watch.clock
        self._timers: TimerClock | None = clock if isinstance(clock, TimerClock) else None
        self._timer: Timer | None = None
        self._tick_lock = threading.Lock()  # a callback running, in whichever thread
        self._thread = threading.Thread(target=self._run, name="rvis-window-watch", daemon=True)

    def __enter__(self) -> Withdrawal:
        if self._timers is not None:
            self._next_tick()
        else:
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._timers is not None:
            with self._tick_lock:  # a callback in another thread finishes first
                if self._timer is not None:
                    self._timer.cancel()
        else:
            self._thread.join()

    def _next_tick(self) -> None:
        assert self._timers is not None
        t = self._timers.monotonic() + self.watch.line.poll_s
        self._timer = self._timers.call_at(t, self._tick)

    def _tick(self) -> None:
        with self._tick_lock:
            if not self._stop.is_set() and not self._look():
                self._next_tick()

    def _run(self) -> None:
        w = self.watch
        while not w.clock.wait(self._stop, w.line.poll_s):
            if self._look():
                return

    def _look(self) -> bool:
        """Poll the PLC; True when the window is gone (the robot aborted)."""
        w = self.watch
        try:
            w.poll()
        except DeviceError as exc:  # the PLC link itself failed: stop the robot too
            self.error = exc
        if self.error is None and self._ready():
            return False
        self.why = self._reason()
        self.withdrawn = True
        try:
            self._abort()
        except DeviceError as exc:
            self.error = self.error or exc
        return True

    def _reason(self) -> str:
        w, i = self.watch, self.watch.inputs
        if self.error is not None:
            return f"PLC link lost: {self.error}"
        if not w.alive:
            return "PLC heartbeat lost"
        if i is not None and not i.line_running:
            return "line stopped"
        return "window withdrawn" if self._ready == w.ready else "body withdrawn"


@dataclass
class WindowReport:
    """What happened in one window."""

    window: int
    slots: list[int] = field(default_factory=list)
    measured: int = 0
    rejected: int = 0
    withdrawn: str = ""  # why, when the PLC took the window back
    overrun: bool = False  # the robot moved and was home only after the window's expected end
    note: str = ""

    def to_json(self) -> dict[str, object]:
        """The `window` event's fields: `withdrawn` a boolean (as the counters count it), its
        reason apart (`withdrawn_reason`, null when the window was not withdrawn)."""
        out: dict[str, object] = dict(self.__dict__)
        out["withdrawn"] = bool(self.withdrawn)
        out["withdrawn_reason"] = self.withdrawn or None
        return out


class Cycle:
    """Runs windows: `run_window` once `watch.fresh_window()` is true."""

    def __init__(
        self,
        watch: WindowWatch,
        measurer: SphereMeasurer,
        schedule: Schedule,
        position: Callable[[], int],
        record: Recorder,
        choose: Callable[[Sequence[Slot]], Slot] | None = None,
        slots_wanted: Callable[[], int] | None = None,
    ) -> None:
        """`choose`: the pick among the slots that fit (adaptive scheduling, a step being
        attributed), else cycled; `slots_wanted()`: how many slots this window may measure,
        asked before each (default [line] slots_per_window)."""
        self.watch, self.measurer, self.schedule = watch, measurer, schedule
        self.position, self.record, self.choose = position, record, choose
        self.slots_wanted = slots_wanted or (lambda: watch.line.slots_per_window)
        self.plc, self.clock, self.line = watch.plc, watch.clock, watch.line

    def run_window(self, window: int) -> WindowReport:
        """Measure in the open window and come home; raises a DeviceError for a fault."""
        report = WindowReport(window)
        assert self.watch.opened_t is not None
        end_t = self.watch.opened_t + self.line.window_s
        self.watch.used_t = self.watch.opened_t
        self.plc.set_signals(busy=True, done=False, fault=False)
        with Withdrawal(self.watch, self.measurer.robot.abort) as guard:
            self._slots(window, guard, report)
        if guard.error is not None:
            raise guard.error
        if guard.withdrawn:
            report.withdrawn = guard.why
            if self.measurer.robot.fault is not None:
                self.measurer.robot.reset()  # our own abort latched it
        self.measurer.go_home()
        # the robot left home and came back after the window's end (a window seen too late,
        # in which nothing moved, is no overrun: the cell was never occupied)
        moved = bool(report.slots) or bool(guard.withdrawn) or report.note == "robot brought home"
        report.overrun = moved and self.clock.monotonic() > end_t
        self.plc.set_signals(busy=False, done=not guard.withdrawn, fault=False)
        return report

    def _slots(self, window: int, guard: Withdrawal, report: WindowReport) -> None:
        sensor_s = self.measurer.sensor.duration_s
        if not self.measurer.at_home():  # back from a fault: first come home in a window
            report.note = "robot brought home"
            return
        while len(report.slots) < self.slots_wanted():
            q_now = self.measurer.robot.joints_deg()
            remaining = self.watch.remaining_s()
            slot = self.schedule.next_fitting(
                self.position(), q_now, remaining, sensor_s, self.choose
            )
            if slot is None or guard.withdrawn:
                report.note = report.note or ("" if guard.withdrawn else "no slot fits")
                return
            self._slot(slot, window, guard, report)

    def _slot(self, slot: Slot, window: int, guard: Withdrawal, report: WindowReport) -> None:
        try:
            self.measurer.move_to(slot.q_deg)
        except DeviceError:
            if not guard.withdrawn:
                raise
            return  # the motion error of our own abort
        if guard.withdrawn:
            return
        try:
            reading: Reading | None = self.measurer.sensor.measure(slot.target)
            reason = ""
        except Rejected as exc:
            reading, reason = None, str(exc)
        self.record(slot, window, reading, reason)  # committed before done
        report.slots.append(slot.index)
        report.measured += reading is not None
        report.rejected += reading is None
