"""What the service's collaborators use of it: `LineHost`, the service as the operator's
commands (app.line.operator), the one estimator (app.line.jumps), the status reply
(app.line.status), the start (app.line.startup), the loop (app.line.window_loop), the slot
choice (app.line.slot_choice), the measurements' record (app.line.recording), the
recalibration decisions (app.line.decisions), the versions put in force (app.line.versions)
and the alarms and faults (app.line.faults) see it. `app.line.service.Service` is the one
implementation; the collaborators import this protocol, not the service, so no import runs back
to it."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from app.line.accuracy import AccuracyRecord
from app.line.beyond_knock import MaintenanceNeed
from app.line.body_cycle import BodyCycle
from app.line.cycle import Cycle, WindowWatch
from app.line.decision_state import DecisionState
from app.line.events import EventBus
from app.line.fault_record import FaultRecord
from app.line.inline_seq import InlineSequential, SequentialCandidate
from app.line.measure import SphereMeasurer
from app.line.params_store import ParamsStore
from app.line.recalib import Posterior, Recalibrator, RecalOutcome
from app.line.roles import Roles
from app.line.schedule import Schedule
from app.line.sensor_watch import SensorWatch
from app.line.settings import ServiceSettings
from app.line.statedir import StateDir
from app.line.states import State
from app.line.station import Station
from app.line.store import StorageError, Store
from app.line.sweeps import SweepArchive
from calib.model import SystemModel
from drivers.clock import Clock

F64 = NDArray[np.float64]


class LineHost(Protocol):
    """The service's state and the actions its collaborators may take on it."""

    # what it is made of
    settings: ServiceSettings
    clock: Clock
    station: Station
    schedule: Schedule
    spheres: dict[str, F64]
    paths: StateDir
    roles: Roles
    store: Store
    params: ParamsStore
    bus: EventBus
    recalibrator: Recalibrator
    sequential: InlineSequential | None
    watch: WindowWatch
    measurer: SphereMeasurer
    cycle: Cycle
    body_cycle: BodyCycle | None  # the bodies' features (None: no feature plan)
    sensor_watch: SensorWatch
    sweeps: SweepArchive
    log: logging.Logger
    wake: threading.Event  # set: the loop looks at its queue now
    after_window: Callable[[], None] | None  # called in the loop's thread after each window

    # the parameters in force
    model: SystemModel
    service_model: SystemModel  # [service] model: what the service identifies
    x: F64
    version: int

    # the decision state (snapshot / restore)
    state: State
    decision: DecisionState  # what it decided and remembers across a restart
    accuracy: AccuracyRecord  # what the cell states about its accuracy (app.line.accuracy)

    # faults: the storage's and the devices' (app.line.fault_record)
    fault: FaultRecord

    @property
    def cell_temp_c(self) -> float | None: ...

    def status(self) -> dict[str, Any]: ...

    def stopping(self) -> bool: ...

    def reraise_crash(self) -> None: ...

    def current_params(self) -> tuple[int, SystemModel, F64] | None: ...

    def snapshot(self) -> dict[str, Any]: ...

    def save_state(self) -> None: ...

    def restore(self) -> None: ...

    def set_state(self, state: State) -> None: ...

    def alarm(self, code: str, message: str, priority: str = "high") -> int: ...

    def clear_alarms(self, code: str, t: float | None = None) -> int: ...

    def storage_fault(self, exc: StorageError) -> None: ...

    def note_device_error(self, exc: BaseException) -> str | None: ...

    def maintenance_needed(self, need: MaintenanceNeed) -> None: ...

    def sphere_residuals(self) -> dict[str, dict[str, Any]]: ...

    def rolling_set(
        self,
    ) -> tuple[list[Mapping[str, Any]], list[Mapping[str, Any]]] | None: ...

    def recal_wait(self) -> str: ...

    def posterior(self) -> Posterior | None: ...

    def applies_automatically(self) -> bool: ...

    def recal_done(self, out: RecalOutcome | SequentialCandidate) -> None: ...

    def apply_calibration(self, cal_id: int, uid: int | None, source: str) -> int: ...

    def in_force(self, version: int, cal_id: int | None, source: str, uid: int | None) -> None: ...
