"""`rvis commission --sim`: the commissioning on the simulated line. The line (fakes/line.py,
the same one `rvis run --sim` uses) runs every device peer on loopback from one simulated cell,
steady (no warm-up, no knock: a cell is commissioned cold and still); the commissioning opens
them through the real drivers, as on a real cell. What the simulated cell supplies beyond the
devices: the sensor-calibration targets (chessboards and flat targets rendered by its true
sensor, written as a camera would record them), the geometric sphere measurement of fast runs
(`geometric`: the true centre plus the sensor noise, no rendering), and the truth for the
report (the true error of a calibration at the line's validation positions; never checked).
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from app.commission.context import Context
from app.config import CellConfig
from app.config.line import SweepSettings
from app.formats.sweeps import write_image, write_sweep
from app.line.measure import SphereSensor, SweepSensor
from app.sim.cell import make_cell
from app.sim.line_setup import geometric_sensor, simline_settings
from app.sim.truth import EndToEndTruth, true_rmse_mm
from fakes.line import SimLine
from fakes.render_targets import render_calibration_set
from vision.sensor_model import SensorModel, dumps_sensor_model

#: the simulated rendered sensor's edge placement allowances per side [mm] by feature type
#: (`[sensor] edge_u_mm`, a round hole's; `edge_u_slot_mm`, a slot's), as its acceptance on
#: certified bores and slots found them: `bench/edge.py --seeds 3` (holes of 6, 12 and 20 mm
#: and an 8 x 20 mm slot, tilted 0-15 degrees and rolled, 174 sizes): the least with which
#: 95 % of the certified sizes are within their U95 (more than the moments' 1.9 and 5.7 um: the
#: errors' tails are heavier than normal; docs/results/body.md)
RENDERED_EDGE_U_MM = {"hole": 0.0022, "slot": 0.0064}

F64 = NDArray[np.float64]


class SimCommissioning:
    """`with SimCommissioning(cfg, seed, geometric=True) as sim: sim.urls ...`"""

    def __init__(
        self,
        cfg: CellConfig,
        seed: int,
        *,
        geometric: bool,
        waiting: Callable[[str], None] | None = None,
        world_s: float | None = None,
        start_epoch: float | None = None,
        world: CellConfig | None = None,
    ) -> None:
        """waiting: told in one line, at once, when the simulated camera must wait for another
        simulation's (which it then does for as long as that one runs). world_s: the world's
        time when a maintenance procedure runs on a commissioned cell (`rvis maintain --sim`):
        the world as the line left it (warm, knocked, its maintenance event happened: the
        cell file's [simline]); None: a commissioning's steady, cold cell. start_epoch: the
        Unix time its clock starts at (default now; a procedure on a directory whose simulated
        line ran ahead of the wall clock continues after it: `continued_epoch`). world: the
        cell file the simulated world is built from (default cfg; a commissioned directory's
        is `line_run.world_of`'s)."""
        self.cfg, self.seed, self.geometric = cfg, seed, geometric
        self.cell = make_cell(world or cfg, seed=seed)
        # the line of `rvis run --sim`, steady, with its camera either way, in virtual time as
        # fast as the CPU: the robot's motions, the sweeps and the procedure's waits
        # (Context.clock) make it pass, so what the world does meanwhile (a warm cell cooling,
        # a procedure's thermal state) is the same on a loaded machine as on an idle one
        line = simline_settings(cfg, geometric=True)
        settings = replace(
            line, camera=True, camera_timed=not geometric, clock="virtual", scale=None
        )
        if world_s is None:
            settings = replace(settings, warmup=None, knock=None, maintenance=None)
        else:
            settings = replace(settings, world_s=world_s, start_epoch=start_epoch)
        if waiting is not None:
            settings = replace(settings, camera_wait_s=None, camera_on_wait=waiting)
        self.line = SimLine(self.cell, settings)
        self._stack = ExitStack()
        self.station: Any = None
        self.truth: EndToEndTruth | None = None
        self._truth_key = ""  # the sensor calibration self.truth measures with, as its file
        self._placed = 0

    def __enter__(self) -> Self:
        self._stack.enter_context(self.line)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    @property
    def urls(self) -> dict[str, str]:
        return self.line.urls

    def open_station(self, cfg: CellConfig, trace: Any = None) -> tuple[CellConfig, Any]:
        """The simulated line's devices opened through the real drivers as a guided procedure
        opens them (app.commission.context.open_station), and the cell file with the line's
        PLC settings; the station closes with this object."""
        from app.commission.context import open_station
        from app.sim.line_setup import with_simulated_plc

        cfg = with_simulated_plc(cfg)
        station = open_station(cfg, self.urls, trace)
        self._stack.callback(station.close)
        self.station = station
        return cfg, station

    def context_fields(self) -> dict[str, Any]:
        """What a guided procedure's Context takes from the simulated line: how a sphere is
        measured, how targets are captured, where the validation sphere is placed, and the
        truth for the report, and the line's clock (the procedure's time and its waits)."""
        return {
            "sphere_sensor": self.sphere_sensor,
            "capture": self,
            "truth": self,
            "placement": self,
            "clock": self.line.clock,
        }

    def sphere_sensor(self, model: SensorModel) -> SphereSensor:
        """The geometric sensor of fast runs, or the real sweep through camera and galvo."""
        if self.geometric:  # the sweep's time passes as the rendered one's frames do
            return geometric_sensor(self.line, self._sweep().duration_s)
        assert self.station is not None and self.station.camera is not None
        return SweepSensor(self.station.camera, self.station.galvo, model, self._sweep())

    def _sweep(self) -> SweepSettings:
        from app.line.settings import from_cell

        return from_cell(self.cfg).sweep

    def capture(self, calib_dir: Path, ctx: Context) -> None:
        """The targets the engineer would record, rendered by the cell's true sensor."""
        c = ctx.cfg.commission
        ctx.ask(f"record {c.chessboards} chessboard views and {c.flat_targets} flat targets?")
        rng = np.random.default_rng([self.seed, 11])
        cs = render_calibration_set(
            self.cell.sensor,
            rng,
            n_chessboards=c.chessboards,
            n_targets=c.flat_targets,
            n_commands=9,
        )
        for k, board in enumerate(cs.chessboards):
            write_image(calib_dir / "chessboards" / f"board_{k:02d}.png", board)
        for k, (board, frames) in enumerate(cs.targets):
            pose = calib_dir / "targets" / f"pose_{k:02d}"
            write_image(pose / "board.png", board)
            write_sweep(pose, list(frames), list(cs.commands_v))

    def step_started(self, name: str, failed_before: int) -> None:
        """A commissioning step starts, after `failed_before` runs of it that failed their
        checks: the camera's image noise is that run's draw (fakes.cell: a step resumed after
        a kill renders the frames of an uninterrupted run; one run again after a failure sees
        new noise, as on a real cell, instead of failing the same way at every rerun)."""
        self.cell.noise_draw = failed_before

    def place_sphere(self, target_id: str, p_part_mm: F64) -> None:
        """The engineer puts the validation sphere's nest near p_part_mm: within a few
        millimetres (3 mm RMS per axis, seeded); the tracker measures where it really is."""
        rng = np.random.default_rng([self.seed, 41, self._placed])
        self._placed += 1
        self.cell.place_sphere(target_id, np.asarray(p_part_mm) + rng.normal(0.0, 3.0, 3))

    def remove_sphere(self, target_id: str) -> None:
        self.cell.remove_sphere(target_id)

    def sensor_errors(self, model: SensorModel) -> dict[str, float]:
        """How far a sensor calibration is from the true sensor: focal lengths and principal
        point [px]."""
        true, K = self.cell.sensor, model.camera.K
        return {
            "fx_error_px": float(K[0, 0] - true.fx_px),
            "fy_error_px": float(K[1, 1] - true.fy_px),
            "cx_error_px": float(K[0, 2] - true.cx_px),
            "cy_error_px": float(K[1, 2] - true.cy_px),
        }

    @property
    def sensor_edge_u_mm(self) -> dict[str, float] | None:
        """The simulated sensor's edge placement allowances per side [mm] by feature type, as
        its acceptance on certified bores and slots found them (`[sensor] edge_u_mm`,
        `edge_u_slot_mm`; None: the geometric path, whose edge points are the true edge's plus
        noise)."""
        return None if self.geometric else dict(RENDERED_EDGE_U_MM)

    def true_rmse_mm(self, model: Any, x: F64, sensor_model: SensorModel) -> float:
        """The end-to-end true error [mm, RMS] of parameters x at the line's validation
        positions: on the rendered path measured through `sensor_model`, on the geometric path
        the kinematic error (app/sim/truth.py)."""
        in_use = None if self.geometric else sensor_model
        # each step loads the calibration again: the same file keeps its views' corrections
        key = "" if in_use is None else dumps_sensor_model(in_use)
        if self.truth is None or key != self._truth_key:
            self.truth = EndToEndTruth(self.cell.sensor, in_use, self._sweep().commands_v())
            self._truth_key = key
        return true_rmse_mm(self.line, self.truth, model, x)
