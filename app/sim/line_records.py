"""What a run of the simulated line reports: a record per window (the true error of the
parameters in force, the U95 stated) and the run's summary (app/sim/line_run.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import RvisError

F64 = NDArray[np.float64]


@dataclass
class WindowRecord:
    """The line after one window: sim time [h], temperature, true RMSE of the parameters in
    force and of the commissioning parameters [mm], the parameters version, and the sim time
    [h] the window opened."""

    window: int
    t_h: float
    temp_c: float
    rmse_mm: float
    rmse_commissioning_mm: float
    version: int
    t_open_h: float = float("nan")  # when the window opened (the version was in force then)
    # the U95 [mm] the service stated for the window's bodies (None: none stated), and whether
    # they are in a suspect interval (known once the run ended: a later interval may reach
    # back; `rvis run --sim`: the window's body is one `rvis state suspects` lists, by
    # SimulatedLineRun.mark_suspect; the shift's scoring: app.sim.shift_score.mark_suspect)
    u95_mm: float | None = None
    suspect: bool = False
    body: int | str | None = None  # the body the PLC clamped in the window (None: none read)
    within_u95: float | None = None  # the share of validation points whose true error <= U95
    p95_mm: float = float("nan")  # the 95th percentile of the validation points' true errors
    targets: list[str] = field(default_factory=list)  # the spheres the window measured


@dataclass
class SimRunSummary:
    """A run of the simulated line in figures: the service's events counted (`count`), the
    true error at its start and end, why it stopped early (maintenance, a fault), its bodies,
    and a record per window."""

    windows: int = 0
    measurements: int = 0
    rejected: int = 0
    overruns: int = 0
    withdrawn: int = 0
    calibrations_applied: int = 0
    calibrations_rejected: int = 0
    alarms: list[str] = field(default_factory=list)
    true_rmse_start_mm: float = float("nan")
    true_rmse_final_mm: float = float("nan")
    # the `maintenance` alarm's text when the service holds the cell for a procedure
    maintenance: str | None = None
    # the device fault's alarm when an unattended run ended in a FAULT nobody clears
    fault: str | None = None
    # the bodies measured (their newest evaluation): how many, nonconforming, with a value
    # undecided within its U95, evaluated again after a correction
    bodies: int = 0
    bodies_nok: int = 0
    bodies_undecided: int = 0
    bodies_reevaluated: int = 0
    records: list[WindowRecord] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "records"} | {
            "timeline": [r.__dict__ for r in self.records]
        }

    def count(self, event: dict[str, Any]) -> None:
        """An event of the service's counted (windows, measurements, recalibrations, alarms)."""
        kind = event["event"]
        if kind == "window":
            self.windows += 1
            self.overruns += bool(event.get("overrun"))
            self.withdrawn += bool(event.get("withdrawn"))
        elif kind == "measurement":
            ok = event.get("status", "ok") == "ok"
            self.measurements += ok
            self.rejected += not ok
        elif kind == "parameters_applied" and event.get("source") == "auto":
            self.calibrations_applied += 1
        elif kind == "calibration" and event.get("status") == "rejected":
            self.calibrations_rejected += 1
        elif kind == "alarm":
            self.alarms.append(str(event.get("message") or event.get("code")))


class LineFaulted(RvisError):
    """An unattended run's service sat in a FAULT that nothing in the run clears (its summary
    holds what was measured up to it)."""

    def __init__(self, summary: SimRunSummary) -> None:
        self.summary = summary
        super().__init__(
            f"the simulated line's service faulted after window {summary.windows} and nobody"
            f" resets an unattended run's line: {summary.fault}"
        )
