"""What every commissioning step works with: the cell file, the state directory, the opened
devices, the engineer's confirmations, and where the cell's own parts differ between a real
cell and the simulated line (how a sphere is measured, how targets are captured).

Every motion goes through `move`: the engineer confirms it (or `--yes` does), it runs at
`[commission] speed_pct`, and the robot's guard (the cell's limits, with that speed as its
maximum) refuses anything else before it leaves the process.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from app.commission.files import SENSOR_FILE, TARGETS_FILE
from app.config import CellConfig
from app.config.cell import SpheresSection
from app.config.line import LineSettings, SweepSettings
from app.formats.files import read_targets
from app.line.measure import SphereSensor
from app.line.statedir import StateDir
from app.line.station import Station, cell_guard
from app.motion import motion_time_s
from drivers.clock import Clock, RealClock
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]


class Declined(Exception):
    """The engineer declined a step or a motion: the commissioning stops here (run it again
    to continue)."""


class TargetCapture(Protocol):
    """Captures the sensor-calibration targets into a folder in the CALIB_DIR layout of
    app/formats/sweeps.py (chessboards/, targets/<pose>/)."""

    def capture(self, calib_dir: Path, ctx: Context) -> None: ...


SensorFactory = Callable[[SensorModel], SphereSensor]


class SpherePlacement(Protocol):
    """Where the cell's own parts differ when a sphere is placed by hand: the simulated line
    puts it in its world (a real cell's engineer does it, asked by `Context.place`)."""

    def place_sphere(self, target_id: str, p_part_mm: F64) -> None: ...

    def remove_sphere(self, target_id: str) -> None: ...


@dataclass
class Context:
    """The commissioning of one cell (see the module docstring)."""

    cfg: CellConfig
    state: StateDir
    station: Station
    confirm: Callable[[str], bool]
    say: Callable[[str], None]
    sphere_sensor: SensorFactory
    capture: TargetCapture
    sensor_file: Path | None = None  # --sensor: a calibration made elsewhere
    sensor_data: Path | None = None  # --sensor-data: targets recorded earlier
    targets_file: Path | None = None  # --targets: the tracker's export
    truth: Any = None  # the simulated line (reports figures against its truth; never checked)
    placement: SpherePlacement | None = None  # the simulated line's hands
    out_dir: Path | None = None  # where results go (default: the commissioning's folder)
    clock: Clock = field(default_factory=RealClock)  # the cell's time: versions, records, waits
    # the robot's time so far [s]: its motions (as the line's motion model estimates them at
    # the commissioning's speed) and the sweeps it stood still for
    robot_s: float = 0.0

    @property
    def folder(self) -> Path:
        return self.out_dir or self.state.commission

    def path(self, name: str) -> Path:
        return self.folder / name

    def ask(self, question: str) -> None:
        """Go on only if the engineer confirms; Declined otherwise."""
        if not self.confirm(question):
            raise Declined(question)

    @property
    def line(self) -> LineSettings:
        """The cell's [line] settings with the commissioning speed."""
        return dataclasses.replace(self.cfg.line, speed_pct=float(self.cfg.commission.speed_pct))

    @property
    def sweep(self) -> SweepSettings:
        return self.cfg.sweep

    def move(self, q_deg: ArrayLike, what: str) -> None:
        """Move the robot to `q_deg` once the engineer has confirmed it."""
        q = np.asarray(q_deg, dtype=float)
        angles = ", ".join(f"{v:.2f}" for v in q)
        self.ask(f"move the robot to {what} (J1..J6 {angles} deg) at {self.line.speed_pct:g} %?")
        start = self.station.robot.joints_deg()
        self.station.robot.move_joints(q, speed_pct=self.line.speed_pct)
        self.robot_s += motion_time_s(start, q, self.line)

    def place(self, target_id: str, p_part_mm: F64, where: str) -> None:
        """The engineer places the validation sphere (tracker target `target_id`) near
        p_part_mm; confirmed like a motion."""
        self.ask(f"place the validation sphere (tracker target {target_id}) at {where}?")
        if self.placement is not None:
            self.placement.place_sphere(target_id, p_part_mm)

    def remove(self, target_id: str) -> None:
        """The validation sphere leaves the cell (the spheres of the cell file stay)."""
        self.say(f"    remove the validation sphere (tracker target {target_id}) from the cell")
        if self.placement is not None:
            self.placement.remove_sphere(target_id)

    def home(self) -> None:
        """Back home (confirmed like every motion) unless it is there already."""
        if not self.at_home():
            self.move(self.line.home_deg, "home")

    def at_home(self) -> bool:
        q = self.station.robot.joints_deg()
        return bool(np.all(np.abs(q - np.asarray(self.line.home_deg)) <= self.line.home_tol_deg))

    def sensor_model(self) -> SensorModel:
        """The sensor calibration of the sensor step."""
        from vision.sensor_model import load_sensor_model

        return load_sensor_model(self.path(SENSOR_FILE))

    def spheres_part_mm(self) -> dict[str, F64]:
        """The tracker's sphere positions once the spheres step passed, else the cell file's."""
        path = self.path(TARGETS_FILE)
        return read_targets(path) if path.exists() else dict(self.cfg.spheres_part_mm)

    def cell(self) -> CellConfig:
        """The cell file with the tracker's sphere positions (part frame)."""
        spheres = self.spheres_part_mm()
        section = SpheresSection(
            frame="part", positions_mm={k: tuple(map(float, v)) for k, v in spheres.items()}
        )
        return dataclasses.replace(self.cfg, spheres=section, spheres_part_mm=spheres)


def open_station(cfg: CellConfig, urls: dict[str, str], trace: Any = None) -> Station:
    """The cell's devices opened for a guided procedure: the robot's guard at `[commission]
    speed_pct`, the camera at the cell file's settings, the PLC read-only (the line's PLC
    program keeps its outputs)."""
    guard = dataclasses.replace(cell_guard(cfg), max_speed_pct=float(cfg.commission.speed_pct))
    options = {"camera": {"settings": cfg.camera.settings()}, "plc": {"read_only": True}}
    return Station.open(urls, guard=guard, options=options, trace=trace)
