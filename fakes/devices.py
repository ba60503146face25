"""In-process fake backends (the ``fake://`` scheme) on a shared World.

They are real backends of the driver families, not mocks: the family base classes apply the same
policy (safety guard, fault latch, limits) and the fakes raise the same errors as hardware.
Fault injection is explicit (``inject_fault``), never patched in.

On a VirtualClock (``clock=``) the robot lets each motion's duration pass on the clock instead of
waiting it in real time (an abort stops it where it is), and the PLC runs its clamp cycle on the
clock's time: the service's tests then see the same sequence on a loaded machine.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from drivers.camera import Camera, CameraSettings, Frame
from drivers.errors import DeviceConfigError, DeviceFault, DeviceTimeout
from drivers.galvo import Galvo
from drivers.plc import (
    Plc,
    PlcInputs,
    PlcOutputs,
    decode_outputs,
    encode_body_id,
    encode_inputs,
    encode_outputs,
)
from drivers.robot import FloatArray, Robot, RobotStatus
from drivers.tracker import Tracker, TrackerMeasurement, TrackerStatus
from drivers.url import DeviceUrl
from fakes.clock import VirtualClock
from fakes.world import World, frame_in_format

SENSOR_WH = (1296, 966)  # Basler acA1300-30um, Sony ICX445


def _world(url: DeviceUrl, options: dict[str, Any]) -> World:
    world = options.pop("world", None)
    if not isinstance(world, World):
        raise DeviceConfigError(f"{url.raw} needs a world= (a fakes.world.World)")
    return world


def move_along(world: World, target: FloatArray, duration_s: float, stop: threading.Event) -> bool:
    """Interpolate the world's joints to ``target`` over ``duration_s``; False if stopped."""
    start = world.joints_deg()
    t0 = time.monotonic()
    while (frac := (time.monotonic() - t0) / duration_s if duration_s > 0 else 1.0) < 1.0:
        world.set_joints_deg(start + frac * (target - start))
        if stop.wait(min(0.02, duration_s / 10)):
            return False
    world.set_joints_deg(target)
    return True


#: A motion on a VirtualClock passes in steps of at most this [sim s], the joints set after each.
PASS_STEP_S = 0.05


def pass_along(
    world: World, target: FloatArray, duration_s: float, clock: VirtualClock, stop: threading.Event
) -> bool:
    """Move the world's joints to ``target`` while ``duration_s`` passes on the clock (in steps:
    what reads the joints meanwhile, at a sim time, sees them on the way); False if stopped."""
    start = world.joints_deg()
    n = max(1, int(np.ceil(duration_s / PASS_STEP_S)))
    passed = 0.0
    for _ in range(n):
        passed += clock.elapse(duration_s / n, stop)
        frac = min(passed / duration_s, 1.0) if duration_s > 0 else 1.0
        world.set_joints_deg(start + frac * (target - start))
        if stop.is_set():
            return False
    world.set_joints_deg(target)
    return True


class FakeRobot(Robot):
    """Moves the world's robot in joint space; motion time = max |dq| / (speed x override) x
    time_scale, each appended to ``motion_durations_s``; on a VirtualClock (``clock=``) the
    motion time without time_scale passes on the clock."""

    def __init__(
        self,
        world: World,
        *,
        time_scale: float = 1.0,
        clock: VirtualClock | None = None,
        **kw: Any,
    ) -> None:
        super().__init__(**kw)
        self.world, self.time_scale, self.clock = world, float(time_scale), clock
        self._stop = threading.Event()
        self._pending: DeviceFault | None = None
        self.override_pct = 100
        self.motion_durations_s: list[float] = []

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FakeRobot:
        return cls(_world(url, options), **options)

    def inject_fault(self, code: int, message: str = "SRVO-050 collision detect") -> None:
        """The next motion fails with this controller error (as a collision would)."""
        self._pending = DeviceFault(message, code=code)

    def _open(self) -> None:
        self._stop.clear()

    def _close(self) -> None:
        self._stop.set()

    def _read_joints(self) -> FloatArray:
        return self.world.joints_deg()

    def _status(self) -> RobotStatus:
        return RobotStatus(
            servo_ready=True,
            moving=False,
            fault=self._pending is not None,
            override_pct=self.override_pct,
        )

    def _set_override(self, override_pct: int) -> None:
        self.override_pct = override_pct

    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None:
        if self._pending is not None:
            raise self._pending
        self._stop.clear()
        duration = self.guard.duration_s(self.world.joints_deg(), q_deg, speed_pct)
        duration *= 100.0 / self.override_pct
        if duration * self.time_scale > timeout_s:
            raise DeviceTimeout(f"{self.name}: motion would take {duration:.1f} s")
        if self.clock is not None:
            self.motion_durations_s.append(duration)
            if not pass_along(self.world, q_deg, duration, self.clock, self._stop):
                raise DeviceFault(f"{self.name}: motion aborted")
            return
        self.motion_durations_s.append(duration * self.time_scale)
        if not move_along(self.world, q_deg, duration * self.time_scale, self._stop):
            raise DeviceFault(f"{self.name}: motion aborted")

    def _abort(self) -> None:
        self._stop.set()

    def _reset(self) -> None:
        self._pending = None


class FakeGalvo(Galvo):
    """A DAC in memory: stores the command [V], rejects voltages outside +-10 V like the board.
    The camera hands the command to the world, whose true sensor turns it into the mirror angle
    (fakes/render_sensor.py)."""

    def __init__(self, world: World | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.output_v = 0.0
        self._queue: list[tuple[int, str]] = []

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FakeGalvo:
        options.pop("world", None)
        return cls(**options)

    def _open(self) -> None:
        self.output_v = 0.0

    def _close(self) -> None:
        pass

    def _identify(self) -> str:
        return "rvis,FakeDAC,0,1.0"

    def _set_volts(self, volts: float) -> None:
        if abs(volts) > 10.0:
            self._queue.append((-222, "Data out of range"))
        else:
            self.output_v = volts

    def _get_volts(self) -> float:
        return self.output_v

    def _errors(self) -> list[tuple[int, str]]:
        errors, self._queue = self._queue, []
        return errors


class FakeCamera(Camera):
    """Renders the world's frame at each trigger; ``fire_line_trigger()`` is the hardware line."""

    def __init__(self, world: World, *, galvo: Galvo | None = None, **kw: Any) -> None:
        super().__init__(**kw)
        self.world, self.galvo = world, galvo
        self._frames: queue.Queue[Frame] = queue.Queue()
        self._frame_id = 0

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FakeCamera:
        return cls(_world(url, options), **options)

    def _open(self) -> None:
        self._frames = queue.Queue()

    def _close(self) -> None:
        pass

    def _sensor_size(self) -> tuple[int, int]:
        return SENSOR_WH

    def _apply(self, settings: CameraSettings) -> CameraSettings:
        return settings

    def _render(self) -> Frame:
        s = self.settings
        assert s.region is not None
        x, y, w, h = s.region
        galvo_v = self.galvo.volts() if self.galvo is not None and self.galvo.is_open else None
        top = {"Mono8": 255, "Mono12": 4095, "Mono16": 65535}[s.pixel_format]
        full = frame_in_format(self.world, SENSOR_WH, s.exposure_us, s.gain_db, galvo_v, top)
        image = np.ascontiguousarray(full[y : y + h, x : x + w])
        self._frame_id += 1
        return Frame(image, self._frame_id, time.time_ns(), s.exposure_us, s.gain_db)

    def fire_line_trigger(self) -> None:
        """An edge on the hardware trigger line (only honoured in hardware trigger mode)."""
        if self.is_open and self.settings.trigger == "hardware":
            self._frames.put(self._render())

    def _trigger(self) -> None:
        self._frames.put(self._render())

    def _grab(self, timeout_s: float) -> Frame:
        if self.settings.trigger == "free":
            return self._render()
        try:
            return self._frames.get(timeout=timeout_s)
        except queue.Empty as exc:
            raise DeviceTimeout(f"{self.name}: no frame within {timeout_s:g} s") from exc


class FakeTracker(Tracker):
    """Measures the world's targets with seeded Gaussian noise (``noise_mm`` per axis)."""

    def __init__(
        self,
        world: World,
        *,
        seed: int = 0,
        noise_mm: float = 0.005,
        temperature_c: float = 20.0,
        pressure_hpa: float = 1013.25,
        **kw: Any,
    ) -> None:
        super().__init__(**kw)
        self.world, self.noise_mm = world, float(noise_mm)
        self.temperature_c, self.pressure_hpa = temperature_c, pressure_hpa
        self._rng = np.random.default_rng(seed)
        self.in_beam = True

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FakeTracker:
        return cls(_world(url, options), **options)

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _targets(self) -> list[str]:
        return self.world.target_ids()

    def _status(self) -> TrackerStatus:
        return TrackerStatus(ready=True, target_in_beam=self.in_beam)

    def _measure(self, target_id: str, timeout_s: float) -> TrackerMeasurement:
        return measure_target(
            self.world, target_id, self._rng, self.noise_mm, self.temperature_c, self.pressure_hpa
        )


def measure_target(
    world: World,
    target_id: str,
    rng: np.random.Generator,
    noise_mm: float,
    temperature_c: float,
    pressure_hpa: float,
) -> TrackerMeasurement:
    """A noisy tracker measurement of a world target (DeviceFault for an unknown id)."""
    try:
        true = world.target_true_mm(target_id)
    except KeyError as exc:
        raise DeviceFault(f"unknown target {target_id!r}", code=404) from exc
    samples = true + rng.normal(0.0, noise_mm, size=(16, 3))
    point = samples.mean(axis=0)
    rms = float(np.sqrt(np.mean(np.sum((samples - point) ** 2, axis=1))))
    now = datetime.now(UTC).isoformat(timespec="milliseconds")
    return TrackerMeasurement(target_id, point, rms, now, temperature_c, pressure_hpa)


def body_id_of(number: int, fmt: str) -> int | str:
    """How the simulated PLC writes body `number` in format `fmt` (drivers.plc.BODY_ID_WORDS):
    the number itself (u32), or "B" and its last 7 digits (serial8)."""
    return f"B{number % 10**7:07d}" if fmt == "serial8" else number


#: the body's phase opens this far into a clamp period [s]
BODY_START_S = 1.0


@dataclass(frozen=True)
class ClampCycle:
    """The line's clamp cycle: every ``period_s`` the window is open for ``window_s`` (at the
    end of the period). ``time_scale`` < 1 compresses time for tests; the PLC heartbeat ticks
    every ``beat_s``. Every period clamps the next body: period k (0, 1, ...) holds body number
    ``first_body + k`` from its start until its window closes. Pure: the state is a function of
    the elapsed time."""

    period_s: float = 60.0
    window_s: float = 8.0
    beat_s: float = 0.5
    time_scale: float = 1.0
    line_running: bool = True
    first_body: int = 100001
    # the body's own phase: body_ready from BODY_START_S into the period for body_s (0: a
    # PLC program without the bit), before the window
    body_s: float = 0.0

    def __post_init__(self) -> None:
        if not (0 < self.window_s < self.period_s and self.beat_s > 0 and self.time_scale > 0):
            raise DeviceConfigError("clamp cycle needs 0 < window_s < period_s, beat_s > 0")
        free = self.period_s - self.window_s - 2 * BODY_START_S
        if self.body_s < 0 or (self.body_s > 0 and self.body_s > free):
            raise DeviceConfigError("the body's phase must end before the window opens")

    def inputs(self, elapsed_s: float, heartbeat_frozen: bool = False) -> PlcInputs:
        t = elapsed_s / self.time_scale
        phase = t % self.period_s
        window = self.line_running and phase >= self.period_s - self.window_s
        body = self.line_running and BODY_START_S <= phase < BODY_START_S + self.body_s
        beat = 0 if heartbeat_frozen else int(t / self.beat_s) & 0xFFFF
        return PlcInputs(
            window_open=window, line_running=self.line_running, heartbeat=beat, body_ready=body
        )

    def body(self, elapsed_s: float) -> int:
        """The number of the body clamped at `elapsed_s` (the body of the period it falls in)."""
        return self.window_body(int((elapsed_s / self.time_scale) // self.period_s))

    def window_body(self, k: int) -> int:
        """The number of the body clamped in period k, whose window is the k-th (from 0)."""
        return self.first_body + k


def signals_of(out: PlcOutputs) -> tuple[bool, ...]:
    return out.busy, out.done, out.fault, out.body_done, out.body_nok


class FakePlc(Plc):
    """A PLC in memory running a ClampCycle from the moment it is opened (on a VirtualClock,
    ``clock=``: from its sim time 0, the cycle's time_scale applied to its sim seconds as to
    real ones). It holds the clamped body's id in ``body_format`` (drivers.plc.BODY_ID_WORDS;
    None: a PLC program without the body id words)."""

    def __init__(
        self, cycle: ClampCycle | None = None, *, clock: VirtualClock | None = None, **kw: Any
    ) -> None:
        super().__init__(**kw)
        self.cycle, self.clock = cycle or ClampCycle(), clock
        self.body_format: str | None = "u32"
        self.received = PlcOutputs()
        # the newest 1000 changes of busy/done/fault, in order (bounded: soaks run for days)
        self.history: deque[PlcOutputs] = deque(maxlen=1000)
        self.heartbeat_frozen = False
        self._t0 = time.monotonic()

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> FakePlc:
        options.pop("world", None)
        return cls(**options)

    def _connect(self) -> None:
        self._t0 = time.monotonic()

    def _close(self) -> None:
        pass

    def _elapsed(self) -> float:
        if self.clock is not None:
            return self.clock.monotonic() * self.cycle.time_scale
        return time.monotonic() - self._t0

    def _read_input_words(self) -> tuple[int, int]:
        return encode_inputs(self.cycle.inputs(self._elapsed(), self.heartbeat_frozen))

    def _read_body_words(self, count: int) -> tuple[int, ...]:
        if self.body_format is None:
            return (0,) * count  # the words are there, the PLC program never writes them
        body = body_id_of(self.cycle.body(self._elapsed()), self.body_format)
        words = encode_body_id(body, self.body_format)
        return (*words, 0, 0, 0, 0)[:count]

    def _write_output_words(self, words: tuple[int, int]) -> None:
        outputs, old = decode_outputs(words), self.received
        if signals_of(outputs) != signals_of(old):
            self.history.append(outputs)
        self.received = outputs

    def _read_output_words(self) -> tuple[int, int]:
        return encode_outputs(self.received)
