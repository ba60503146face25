"""The simulated line: one simulated cell driving every protocol peer on 127.0.0.1.

    with SimLine(cell, SimLineSetup(knock=Knock(at_s=4 * 3600))) as line:
        robot = open_robot(line.urls["robot"])          # the real drivers, over loopback
        ...
        line.truth.validation_centres_sensor_mm()       # the truth now, for the app's report

What runs, all on the line's clock (sim time 0 at the start; the cell's warm-up and knock follow
it). By default a `VirtualClock`: time passes only by what is simulated (the service's waits,
the motions, exposures, read-outs, the DAC's settling), so a seed gives one run whatever the
machine's load; `scale` paces it for a person who watches. `clock="scaled"`: a `ScaledClock`,
the wall clock x `scale` (peers driven by hand, nobody making time pass).

    plc      plc+modbus://127.0.0.1:PORT   Modbus PLC with the clamp cycle (a window of
                                           `window_s` at the end of every `period_s`); it
                                           counts bodies: period k clamps body `first_body` + k
                                           (its id in `body_format`)
    robot    rmi://127.0.0.1:PORT          RMI controller moving the cell's joints; motion time
                                           = max |dq| / (joint speed x speed% x override)
    galvo    scpi+serial:///dev/pts/N      SCPI DAC on a pty; the camera renders its voltage
    camera   aravis://127.0.0.1            Aravis's fake GigE camera streaming frames rendered
                                           from the cell at the current joints and DAC voltage
                                           (off with `camera=False`: geometric runs)
    tracker  tracker+tcp://127.0.0.1:PORT  side-car measuring the true sphere centres + noise

`geometric_centre(target_id)` is the shortcut of long runs (`--geometric`): the true centre in the
true sensor frame at the robot's current joints plus the cell's sensor noise, no rendering.
Faults: `inject`, `clear`, `schedule` (fakes.line_faults); a device switched off and on again
at the same URL: `stop_device`, `start_device` (`rvis devices sim`). Every thread, socket, pty
and the GigE fake are released by `close()` (also when `start()` fails half-way).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fakes.cell import SimulatedCell
from fakes.clock import ScaledClock, VirtualClock
from fakes.devices import BODY_START_S, ClampCycle
from fakes.gv_camera import ADDRESS_WAIT_S, GvCamera
from fakes.line_faults import GALVO_ERROR_CODE, Fault, FaultScheduler, LinePlc, window_bounds_s
from fakes.line_truth import LineTruth, validation_positions
from fakes.rmi_controller import RmiController
from fakes.scpi_dac import ScpiDac
from fakes.tracker_service import TrackerService
from fakes.truth import Knock, Maintenance, Warmup

F64 = NDArray[np.float64]

#: The line's devices, by the family names of the cell file's [devices] table.
DEVICES = ("robot", "camera", "galvo", "tracker", "plc")


@dataclass(frozen=True)
class SimLineSetup:
    """The simulated line. Times in sim seconds. clock "virtual": time passes by the simulated
    durations, paced at `scale` sim seconds per real second (None: as fast as the CPU);
    "scaled": `scale` sim seconds pass per real second, whatever happens."""

    scale: float | None = None
    clock: str = "virtual"  # "virtual" | "scaled"
    start_epoch: float | None = None  # Unix time of sim time 0 (None: now, whole seconds)
    period_s: float = 60.0  # clamp cycle: one window a minute ...
    window_s: float = 20.0  # ... open for its last window_s
    # the body's phase before it (body_ready), at most what the period leaves before the window
    # (a setup whose period was shortened keeps what fits); 0: a PLC without the bit
    body_s: float = 0.0
    beat_s: float = 0.5  # PLC heartbeat period
    first_body: int = 100001  # the number of the body clamped in the world's first period
    # the world's time at sim time 0: a line that continues an earlier run's world (warm,
    # knocked, its body count on) starts this far into it
    world_s: float = 0.0
    body_format: str = "u32"  # how the PLC writes it: "u32" (the number) or "serial8"
    warmup: Warmup | None = field(default_factory=Warmup)
    knock: Knock | None = None
    maintenance: Maintenance | None = None  # a change beyond a knock (fakes.truth)
    camera: bool = True  # start the GigE fake (False: geometric runs, no rendering)
    # its frames take the line's time (False: a geometric procedure's camera, which is only
    # probed: a probe re-triggered under a loaded machine would move the world on by a frame)
    camera_timed: bool = True
    camera_address: str = "127.0.0.1"
    # how long the camera waits for its address when another simulation's holds it (None: as
    # long as it takes: a user's command), and who is told at once that it waits
    camera_wait_s: float | None = ADDRESS_WAIT_S
    camera_on_wait: Callable[[str], None] | None = None
    n_validation: int = 100
    camera_readout_s: float = 0.033  # virtual clock: a frame's read-out after its exposure
    galvo_settle_s: float = 0.002  # virtual clock: the mirror settling after a command
    # the simulated robot's motion (fakes.rmi_controller): each joint's time to its speed and
    # the settling at a FINE stop, inside the planner's allowances ([line] accel_s 0.4,
    # settle_s 0.2), as a real robot's would be measured to be
    robot_accel_s: float = 0.3
    robot_settle_s: float = 0.15
    # the DAC's stable name (a symlink re-pointed when it comes back, as udev's
    # /dev/serial/by-id/...): the galvo's URL names it; None: the pty itself
    galvo_link: str | None = None

    def __post_init__(self) -> None:
        if not (0 < self.window_s < self.period_s and self.beat_s > 0):
            raise ValueError("line needs 0 < window_s < period_s and beat_s > 0")
        if self.clock not in ("virtual", "scaled"):
            raise ValueError(f"clock must be virtual or scaled, got {self.clock!r}")
        if self.scale is not None and not self.scale > 0:
            raise ValueError("scale must be > 0")
        if self.clock == "scaled" and self.scale is None:
            raise ValueError("a scaled clock needs a scale")
        if self.camera_readout_s < 0 or self.galvo_settle_s < 0:
            raise ValueError("camera_readout_s and galvo_settle_s must be >= 0")
        if self.n_validation < 1:
            raise ValueError("n_validation must be >= 1")
        if self.body_format not in ("u32", "serial8") or not 0 < self.first_body < 2**32:
            raise ValueError("body_format must be u32 or serial8, first_body 1..2**32-1")
        if not self.world_s >= 0:
            raise ValueError("world_s must be >= 0")

    @property
    def cycle(self) -> ClampCycle:
        return ClampCycle(
            period_s=self.period_s,
            window_s=self.window_s,
            body_s=min(self.body_s, max(self.period_s - self.window_s - 2 * BODY_START_S, 0.0)),
            beat_s=self.beat_s,
            first_body=self.first_body + math.ceil(self.world_s / self.period_s),  # periods begun
        )


class _LineWorld:
    """The cell as the peers' World, with the camera rendering the DAC's voltage (the GigE
    fake passes no galvo command: the mirror is driven by the DAC, not by the camera)."""

    def __init__(self, cell: SimulatedCell, dac: ScpiDac) -> None:
        self.cell, self.dac = cell, dac

    def set_joints_deg(self, q_deg: ArrayLike) -> None:
        self.cell.set_joints_deg(q_deg)

    def joints_deg(self) -> F64:
        return self.cell.joints_deg()

    def target_ids(self) -> list[str]:
        return self.cell.target_ids()

    def target_true_mm(self, target_id: str) -> F64:
        return self.cell.target_true_mm(target_id)

    def render_frame(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_deg: float | None
    ) -> F64:
        return self.cell.render_frame_v(width, height, exposure_us, gain_db, self.dac.volts)

    def render_counts(
        self, width: int, height: int, exposure_us: float, gain_db: float, galvo_deg: float | None
    ) -> tuple[NDArray[np.uint16], int]:
        return self.cell.render_counts_v(width, height, exposure_us, gain_db, self.dac.volts)


class SimLine:
    """Every peer of the line on loopback, driven by one simulated cell (module docstring)."""

    def __init__(self, cell: SimulatedCell, settings: SimLineSetup | None = None) -> None:
        self.cell = cell
        self.settings = settings or SimLineSetup()
        s = self.settings
        # sim time 0 is when every peer is up (start), not when the line object is built
        self.clock: VirtualClock | ScaledClock
        self.virtual: VirtualClock | None = None
        if s.clock == "scaled":
            assert s.scale is not None
            self.clock = ScaledClock(s.scale, s.start_epoch, started=False)
        else:
            # the rendered line's camera (Aravis's thread) and DAC (its server thread) charge
            # their durations from threads of their own: not strict, a second mover would
            # wait for its turn (none does on a sweep: the service waits for each answer;
            # `turns_waited`, tests/sim/test_rendered_seed.py)
            strict = not self.settings.camera
            self.clock = self.virtual = VirtualClock(s.start_epoch, pace=s.scale, strict=strict)
        self._stack = ExitStack()
        self.dac = ScpiDac(clock=self.virtual, settle_s=s.galvo_settle_s, link=s.galvo_link)
        self.world = _LineWorld(cell, self.dac)
        seed = cell.settings.seed
        self.plc = LinePlc(self.settings.cycle, self.clock)
        self.plc.body_format = s.body_format
        self.controller = self._controller()
        self.tracker = TrackerService(
            self.world, seed=_derived_seed(seed, 6), noise_mm=cell.settings.tracker_noise_mm
        )
        self.camera: GvCamera | None = None
        if self.settings.camera:
            _ = cell.sensor.pixel_rays  # built once (~1-3 s) now, not inside the first grab
            cell.warm_up()  # and the first rendering's one-time costs
            sensor_wh = (cell.sensor.width_px, cell.sensor.height_px)
            self.camera = GvCamera(
                self.world,
                address=s.camera_address,
                sensor_wh=sensor_wh,
                clock=self.virtual if s.camera_timed else None,
                readout_s=s.camera_readout_s,
                wait_s=s.camera_wait_s,
                on_wait=s.camera_on_wait,
            )
        rng = np.random.default_rng([seed, 8])
        self.truth = LineTruth(cell, validation_positions(cell, self.settings.n_validation, rng))
        self.plc.temperature = self.truth.temp_c  # the PLC's cell temperature word
        self.faults = FaultScheduler(self.clock, self.inject)
        self._started = False
        self.stopped: set[str] = set()  # the devices switched off (`stop_device`)

    # -- life cycle -------------------------------------------------------------------------
    def start(self) -> Self:
        if self._started:
            raise RuntimeError("the simulated line is already started")
        s = self.settings
        self.cell.set_timeline(
            self.clock,
            warmup=s.warmup,
            knock=s.knock,
            world_s=s.world_s,
            maintenance=s.maintenance,
        )
        try:
            for peer in (self.plc, self.controller, self.dac, self.tracker, self.camera):
                if peer is not None:
                    self._stack.enter_context(peer)
            self.faults.start()
            self._stack.callback(self.faults.close)
            self.clock.start()
        except BaseException:
            self._stack.close()
            raise
        self._started = True
        return self

    def close(self) -> None:
        """Stop every peer (idempotent)."""
        if self.camera is not None:
            self.camera.resume()  # a stalled fake camera still closes cleanly; resume anyway
        self._stack.close()
        self._started = False

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def urls(self) -> dict[str, str]:
        """Device URLs for the cell file's [devices] table (family -> URL)."""
        if not self._started:
            raise RuntimeError("the simulated line is not started")
        host = "127.0.0.1"
        urls = {
            "plc": f"plc+modbus://{host}:{self.plc.port}",
            "robot": f"rmi://{host}:{self.controller.port}",
            "galvo": f"scpi+serial://{self.dac.port}",
            "tracker": f"tracker+tcp://{host}:{self.tracker.port}",
        }
        if self.camera is not None:
            urls["camera"] = f"aravis://{self.camera.camera_id}"
        return urls

    # -- switching a device off and on ----------------------------------------------------------
    def families(self) -> list[str]:
        """The devices of this line (the camera only when it has one)."""
        return [f for f in DEVICES if f != "camera" or self.camera is not None]

    def stop_device(self, family: str) -> None:
        """Switch one device off, as its power or cable going: its port closes (the robot
        controller, the tracker, the PLC: connection refused; the galvo's pty vanishes; the
        camera no longer answers on its address). Its URL stays the same (`start_device`)."""
        self._check_family(family)
        if family in self.stopped:
            return
        if family == "galvo":
            self.dac.unplug()
        elif family == "camera":
            assert self.camera is not None
            self.camera.close()
        else:
            server = self._server(family)
            server._want_port = server.port  # when it comes back, on the same port
            server.close()
        self.stopped.add(family)

    def start_device(self, family: str) -> None:
        """Switch a device off by `stop_device` on again, at the same URL, as after a power
        cycle: the robot controller without its alarms, the PLC with its heartbeat running and
        its window back (its clamp cycle follows the line's clock as before), the camera
        streaming."""
        self._check_family(family)
        if family not in self.stopped:
            return
        if family == "galvo":
            self.dac.replug()
        elif family == "camera":
            assert self.camera is not None
            self.camera.start()
        elif family == "robot":
            # a controller starts afresh (its motion worker was shut down with it)
            port = self.controller.port
            self.controller = self._controller(port)
            self._stack.enter_context(self.controller)
        else:
            if family == "plc":
                self.plc.heartbeat_frozen = False
                self.plc.restore_window()
            self._server(family).start()
        self.stopped.discard(family)

    def _controller(self, port: int = 0) -> RmiController:
        """The robot controller on `port` (0: a free one), moving as the setup's robot does."""
        s = self.settings
        return RmiController(
            self.world,
            clock=self.clock,
            port=port,
            accel_s=s.robot_accel_s,
            settle_s=s.robot_settle_s,
        )

    def _server(self, family: str) -> LinePlc | RmiController | TrackerService:
        """The TCP peer of a network device."""
        servers: dict[str, LinePlc | RmiController | TrackerService] = {
            "plc": self.plc,
            "robot": self.controller,
            "tracker": self.tracker,
        }
        return servers[family]

    def _check_family(self, family: str) -> None:
        if not self._started:
            raise RuntimeError("the simulated line is not started")
        if family not in self.families():
            raise ValueError(f"no device {family!r} on this line (one of {self.families()})")

    # -- measuring without images -----------------------------------------------------------
    def geometric_centre(self, target_id: str, sweep_s: float = 0.0) -> F64:
        """The true centre (3,) [mm] of sphere `target_id` in the true sensor frame at the
        robot's current joints and the sim time at the end of the sweep, plus the cell's sensor
        noise. sweep_s: the sweep's duration, which passes on a VirtualClock first (no camera
        charges it on this path). Raises fakes.cell_spec.NotVisible outside the measuring volume."""
        if self.virtual is not None:
            self.virtual.elapse(sweep_s)
        return self.cell.measure_target(target_id)

    # -- clamp windows ----------------------------------------------------------------------
    def window_bounds_s(self, k: int) -> tuple[float, float]:
        """Sim times at which clamp window k opens and closes (the PLC's own schedule)."""
        return window_bounds_s(self.settings.cycle, k)

    def body_number_now(self) -> int:
        """The number of the body clamped now (the PLC's cycle at the clock's time)."""
        return self.settings.cycle.body(self.clock.monotonic() - self.plc.t0)

    def elapse(self, duration_s: float) -> None:
        """What the line does for duration_s takes that long on a VirtualClock (no device
        charges it on the geometric path)."""
        if self.virtual is not None:
            self.virtual.elapse(duration_s)

    def window_body(self, k: int) -> int | str:
        """The id of the body the PLC clamps in period k, whose window is clamp window k (as
        the PLC writes it in its body id words)."""
        return self.plc.body(self.window_bounds_s(k)[0])

    # -- faults -----------------------------------------------------------------------------
    def inject(self, fault: Fault | str) -> None:
        """Play a fault now (see fakes.line_faults for what each one does)."""
        fault = Fault(fault)
        if fault is Fault.PLC_HEARTBEAT_LOSS:
            self.plc.heartbeat_frozen = True
        elif fault is Fault.WINDOW_WITHDRAWN:
            self.plc.withdraw_window()
        elif fault is Fault.ROBOT_DISCONNECT:
            self.controller.fail_next("FRC_JointMotionJRep", "disconnect")
        elif fault is Fault.CONTROLLER_ALARM:
            self.controller.fail_next("FRC_JointMotionJRep", "system_fault")
        elif fault is Fault.CAMERA_TIMEOUT:
            if self.camera is None:
                raise ValueError("camera_timeout needs the camera (SimLineSetup.camera)")
            self.camera.stall()
        elif fault is Fault.GALVO_ERROR:
            self.dac.fail_next("SOUR:VOLT", GALVO_ERROR_CODE)

    def clear(self, fault: Fault | str) -> None:
        """End a lasting fault (heartbeat, withdrawn window, camera); the one-shot faults end
        when they have been played."""
        fault = Fault(fault)
        if fault is Fault.PLC_HEARTBEAT_LOSS:
            self.plc.heartbeat_frozen = False
        elif fault is Fault.WINDOW_WITHDRAWN:
            self.plc.restore_window()
        elif fault is Fault.CAMERA_TIMEOUT and self.camera is not None:
            self.camera.resume()

    def schedule(self, fault: Fault | str, *, window: int, after_s: float = 0.0) -> threading.Event:
        """Play `fault` `after_s` sim seconds after clamp window `window` opens; returns an
        event set once it has been played."""
        opens, _ = self.window_bounds_s(window)
        return self.faults.plan(Fault(fault), opens + after_s)


def _derived_seed(seed: int, stream: int) -> int:
    """An int seed for a peer that takes one, derived from the cell's seed and a stream id."""
    return int(np.random.default_rng([seed, stream]).integers(2**31))
