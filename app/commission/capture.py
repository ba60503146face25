"""Capturing the sensor-calibration targets on a real cell with the sensor's own camera and
galvo, guided pose by pose (docs/commissioning.md, "Sensor calibration"):

- `[commission] chessboards` views of the chessboard (9 x 6 inner corners, 2.5 mm squares) at
  the working distance, tilted up to about 25 deg, the laser off;
- `[commission] flat_targets` poses of the flat target (a chessboard beside a matt white face),
  tilted 10-15 deg about alternating axes: its board with the laser off, then the laser on and
  a sweep of 9 commands over `[sweep] span_v` across the white face.

The images go to the CALIB_DIR layout of app/formats/sweeps.py, the same that `rvis sensor
calibrate` reads, so a capture can be checked or redone offline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.commission.context import Context
from app.formats.sweeps import write_image, write_sweep

SWEEP_COMMANDS = 9


class CameraCapture:
    """The capture of a real cell: the engineer places each target when asked."""

    def capture(self, calib_dir: Path, ctx: Context) -> None:
        camera, galvo = ctx.station.camera, ctx.station.galvo
        if camera is None or galvo is None:
            raise RuntimeError("capturing targets needs the camera and the galvo")
        c = ctx.cfg.commission
        for k in range(c.chessboards):
            ctx.ask(f"chessboard view {k + 1}/{c.chessboards} in place, laser off: grab?")
            write_image(calib_dir / "chessboards" / f"board_{k:02d}.png", camera.grab().image)
        span = ctx.sweep.span_v
        commands = np.linspace(-span, span, SWEEP_COMMANDS)
        for k in range(c.flat_targets):
            pose = calib_dir / "targets" / f"pose_{k:02d}"
            ctx.ask(f"flat target pose {k + 1}/{c.flat_targets} in place, laser off: grab?")
            write_image(pose / "board.png", camera.grab().image)
            ctx.ask("laser on: sweep?")
            frames = []
            for v in commands:
                galvo.set_volts(float(v))
                frames.append(camera.grab().image)
            galvo.set_volts(0.0)
            write_sweep(pose, frames, list(commands))
