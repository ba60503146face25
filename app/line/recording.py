"""A window's measurement recorded, and what it signals: `Recording`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do); app.line.cycle.Cycle hands it each visit's reading.

One row per visit (good or rejected) in the transaction of the decision state it changes, with
its residual under the parameters in force (the measured centre's distance from the sphere's
known one). A good measurement goes into the one estimator, which tests it for a jump
(app.line.jumps), counts towards the next recalibration (app.line.decisions) and, with the
sequential estimator, is offered to it; its PS is charted (app.line.sensor_watch: the sensor
changed, not the robot) and its raw sweep kept.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.line.decisions import Decisions
from app.line.host import LineHost
from app.line.jumps import JumpWatch
from app.line.measure import Reading
from app.line.schedule import Slot
from app.line.sensor_watch import SensorWatch
from app.line.states import AlarmCode
from app.line.store import StorageError

F64 = NDArray[np.float64]


class Recording:
    """The visits' measurements stored, on the service `svc`: a good one into the estimator
    (`jumps`) and counted towards the next recalibration (`decisions`)."""

    def __init__(self, svc: LineHost, decisions: Decisions, jumps: JumpWatch) -> None:
        self.svc = svc
        self.decisions = decisions
        self.jumps = jumps

    def position(self) -> int:
        """The schedule's slot the next window starts from (stored)."""
        return self.svc.store.schedule_position()[0]

    def record(self, slot: Slot, window: int, reading: Reading | None, reason: str) -> int:
        """A visit of `slot` in `window`: its reading (None: rejected for `reason`) stored and
        charted; the row's id."""
        svc = self.svc
        e = None
        temp_c = svc.cell_temp_c
        if reading is not None:
            t = None if temp_c is None else np.array([temp_c])
            p = svc.model.points_part(svc.x, slot.q_deg[None], reading.c_sensor_mm[None], temp_c=t)
            e = float(np.linalg.norm(p[0] - svc.spheres[slot.target]))
        row = {
            "t": svc.clock.time(),
            "window": window,
            "slot": slot.index,
            "target": slot.target,
            "q_deg": slot.q_deg.tolist(),
            "c_sensor_mm": None if reading is None else reading.c_sensor_mm.tolist(),
            "status": "ok" if reading is not None else "rejected",
            "reason": reason,
            "quality": {} if reading is None else reading.quality,
            "params_version": svc.version,
            "residual_mm": e,
            "temp_c": temp_c,
            "next_position": (slot.index + 1) % len(svc.schedule),
        }
        with svc.store.batch():  # the row and the decision state it changes, or neither
            row_id = svc.store.add_measurement(row)
            if reading is not None and e is not None:
                self.decisions.counted()
                svc.decision.last_visit[slot.index] = (
                    slot.q_deg.copy(),
                    reading.c_sensor_mm.copy(),
                )
                self.jumps.estimate.observe({**row, "id": row_id})
                if svc.sequential is not None:
                    svc.sequential.offer({**row, "id": row_id})
            svc.save_state()
        if reading is not None:
            self._watch_sensor(reading.quality)
            try:
                svc.sweeps.keep(row_id, reading)
            except OSError as exc:
                raise StorageError(f"raw sweep of measurement {row_id}: {exc}") from exc
        svc.bus.emit(
            "measurement",
            {
                "id": row_id,
                "target": slot.target,
                "slot": slot.index,
                "status": row["status"],
                "residual_mm": e,
                "reason": reason,
            },
        )
        return row_id

    def _watch_sensor(self, quality: dict[str, Any]) -> None:
        """Chart the measurement's PS (app/line/sensor_watch.py): a change says the sensor
        changed, not the robot (the `sensor` alarm)."""
        ps = SensorWatch.ps_of(quality)
        if ps is not None and (text := self.svc.sensor_watch.update(ps)):
            self.svc.alarm(AlarmCode.SENSOR, text, "high")
