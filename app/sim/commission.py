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

from contextlib import ExitStack
from pathlib import Path
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from app.commission.context import Context
from app.config import CellConfig
from app.line.measure import GeometricSensor, SphereSensor, SweepSensor
from app.sensordata import write_image, write_sweep
from app.simulation import make_cell
from fakes.line import LineSettings, SimLine
from fakes.render_targets import render_calibration_set
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]


class SimCommissioning:
    """`with SimCommissioning(cfg, seed, geometric=True) as sim: sim.urls ...`"""

    def __init__(self, cfg: CellConfig, seed: int, *, geometric: bool) -> None:
        self.cfg, self.seed, self.geometric = cfg, seed, geometric
        self.cell = make_cell(cfg, seed=seed)
        s = cfg.simline
        settings = LineSettings(
            scale=s.scale,
            period_s=s.period_s,
            window_s=s.window_s,
            beat_s=s.beat_s,
            warmup=None,
            knock=None,
            camera=True,  # the stripe step needs the camera either way
            n_validation=s.n_validation,
        )
        self.line = SimLine(self.cell, settings)
        self._stack = ExitStack()
        self.station: Any = None

    def __enter__(self) -> Self:
        self._stack.enter_context(self.line)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    @property
    def urls(self) -> dict[str, str]:
        return self.line.urls

    def sphere_sensor(self, model: SensorModel) -> SphereSensor:
        """The geometric sensor of fast runs, or the real sweep through camera and galvo."""
        if self.geometric:
            return GeometricSensor(self.line.geometric_centre)
        assert self.station is not None and self.station.camera is not None
        from app.line.settings import from_cell

        sweep = from_cell(self.cfg).sweep
        return SweepSensor(self.station.camera, self.station.galvo, model, sweep)

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

    def true_rmse_mm(self, model: Any, x: F64) -> float:
        """RMS Euclidean error [mm] of parameters x at the line's validation positions."""
        truth = self.line.truth
        v = truth.validation
        c = truth.validation_centres_sensor_mm()
        temp = np.full(len(v.q_deg), truth.temp_c())
        e = model.points_part(x, v.q_deg, c, temp_c=temp) - v.p_part_mm
        return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))
