"""A window's measurement recorded, and what it signals: `Recorder`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do); app.line.cycle.Cycle hands it each visit's reading.

One row per visit (good or rejected) in the transaction of the decision state it changes: its
residual under the parameters in force, the change of the sphere's centre since the slot's
previous visit, both charted (app.line.drift): slow drift brings the recalibration forward (a
low `drift` alarm), a step (a knock) is flagged and handed to app.line.step_handler (a high
`drift_step` alarm once it is confirmed). A good measurement's PS is charted as well
(app.line.sensor_watch: the sensor changed, not the robot), and its raw sweep kept.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.line.decisions import Decisions
from app.line.drift import residual_mm
from app.line.host import LineHost
from app.line.jumps import JumpWatch
from app.line.measure import Reading
from app.line.schedule import Slot
from app.line.sensor_watch import SensorWatch
from app.line.states import AlarmCode
from app.line.step import StepStatus, step_alarm_text
from app.line.step_fit import MIN_STEP_REFS
from app.line.step_handler import StepHandler
from app.line.store import StorageError

F64 = NDArray[np.float64]


class Recording:
    """The visits' measurements stored and charted, on the service `svc`; a step flagged goes
    to `steps`, a good measurement counts towards the next recalibration (`decisions`)."""

    def __init__(
        self,
        svc: LineHost,
        steps: StepHandler,
        decisions: Decisions,
        jumps: JumpWatch | None = None,
    ) -> None:
        self.svc = svc
        self.steps = steps
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
            p = svc.spheres[slot.target]
            e = residual_mm(svc.model, svc.x, slot.q_deg, reading.c_sensor_mm, p, temp_c)
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
                change = self._change_mm(slot, reading.c_sensor_mm, row_id)
                if self.jumps is not None:
                    self.jumps.observe({**row, "id": row_id})
                else:
                    self._drift(slot.target, e, change, row_id)
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

    def _change_mm(self, slot: Slot, c_sensor_mm: F64, row_id: int) -> float | None:
        """How far the centre moved since this slot's previous visit (same configuration);
        None when there is none, or when it was before a flagged step (the change spans the
        step, already known)."""
        svc = self.svc
        prev = svc.last_visit.get(slot.index)
        prev_id = svc.visit_ids.get(slot.index, 0)
        svc.last_visit[slot.index] = (slot.q_deg.copy(), np.asarray(c_sensor_mm, float).copy())
        svc.visit_ids[slot.index] = row_id
        if prev is None or not np.allclose(prev[0], slot.q_deg, atol=1e-6):
            return None
        if prev_id < svc.change_from_id:
            return None
        return float(np.linalg.norm(np.asarray(c_sensor_mm, float) - prev[1]))

    def _drift(self, target: str, e_mm: float, change_mm: float | None, row_id: int) -> None:
        """A residual signal while the change charts watch is slow drift: the service handles
        it (recalibration brought forward), an advisory `drift` alarm of low priority. A step
        (a change signal, or any signal before the change charts watch) may need a person to
        look at the cell: only measurements from the change point on are used, and a
        `drift_step` alarm of high priority is raised, at once when it cannot be attributed,
        else once the attribution confirms it (app/line/step_handler.py: until then a low
        `drift` alarm; a step attributed to nothing was drift)."""
        svc = self.svc
        for sig in svc.drift.update(target, e_mm, row_id, change_mm):
            where = "all spheres" if sig.stream == "*" else sig.stream
            stat = f"{sig.chart} {sig.value_mm:.3f} > {sig.limit_mm:.3f} mm"
            if sig.family == "residual" and svc.drift.change_watching:
                svc.drift_due = True
                svc.alarm(
                    AlarmCode.DRIFT,
                    f"drift of {where} (residual, {stat}): recalibration brought forward",
                    "low",
                )
                continue
            if svc.drift_onset_id is None:
                svc.drift_onset_id = sig.onset_ref
                # attributed on pairs with the slots' visits before it: in a new cell's first
                # schedule cycle on the slots visited so far (the windows measure them again)
                attribute = sig.family == "change" or len(svc.visit_ids) >= MIN_STEP_REFS
                self.steps.open_step(sig.onset_ref, row_id, attribute=attribute)
            what = "residual" if sig.family == "residual" else "change since the last visit"
            text = f"step of {where} ({what}, {stat}) since measurement {svc.drift_onset_id}"
            if svc.step is not None:
                svc.step.signal = svc.step.signal or text
                if svc.step.status == StepStatus.PROBATION:
                    svc.alarm(AlarmCode.DRIFT, f"{text}: attributing it (a step or drift?)", "low")
                    continue
            svc.alarm(AlarmCode.DRIFT_STEP, step_alarm_text(text), "high")
