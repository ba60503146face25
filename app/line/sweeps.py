"""Optional raw-sweep retention for audit: the last `keep` sweeps as `sweeps/<id>.npz`
(frames and galvo commands of measurement <id>); 0 keeps none. Each file is written atomically
(a kill leaves the old set or the new one, never a torn file); temporary files of a killed
writer are removed at start."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from app.formats.files import replace_atomically
from app.line.measure import Reading


class SweepArchive:
    def __init__(self, directory: Path, keep: int) -> None:
        self.dir, self.n_keep = directory, int(keep)
        for stale in self.dir.glob(".*.tmp"):
            stale.unlink(missing_ok=True)

    def keep(self, measurement_id: int, reading: Reading) -> Path | None:
        """Store the reading's raw sweep (when it has one) and drop the oldest beyond n_keep."""
        if self.n_keep <= 0 or reading.frames is None or reading.commands_v is None:
            return None
        self.dir.mkdir(parents=True, exist_ok=True)
        path = self.dir / f"{measurement_id:08d}.npz"
        data = io.BytesIO()
        np.savez_compressed(data, frames=reading.frames, commands_v=reading.commands_v)
        replace_atomically(path, data.getvalue())
        for old in sorted(self.dir.glob("*.npz"))[: -self.n_keep]:
            old.unlink(missing_ok=True)
        return path
