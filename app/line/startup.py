"""The service's start: the parameters in force (`load_in_force`, before anything runs) and
the start of its loop (`Startup`, a collaborator of app.line.service.Service that sees it as
app.line.host.LineHost, as app.line.operator's commands do).

The parameters in force are `params/current.json` as the database's applied version: damaged
or missing, it is rebuilt from the history version the database says is in force (a
`params_rebuilt` alarm); an apply the database does not know yet is completed at start; a new
state directory gets the initial parameters as its first version.

At start a calibration killed before its apply is applied (auto mode), one killed in flight
runs again. A device that cannot be reached at start (`Station.open(defer_unreachable=True)`:
its URL is right, nothing answers) does not end the process: the service starts in FAULT with
a `device_unreachable` alarm naming the device, answers its socket and OPC UA, and tries to
open it again after 1, 2, 5, 10, then every 30 s of its clock (`DEVICE_RETRY_S`). Nothing has
moved, so once every device is open the alarm clears by itself and the start goes on as usual
(a fault alarm held from before still waits for a reset; a robot away from home is
`robot_not_home`).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.params import plain_document, set_covariance
from app.line.decisions import Decisions
from app.line.faults import Faults, fault_stop
from app.line.host import LineHost
from app.line.operator import Operator
from app.line.params_store import INITIAL_SOURCE, ParamsStore, first_in_force
from app.line.states import FAULT_CODES, AlarmCode, State, utc_text
from app.line.store import Store
from calib.compliance import CompliantModel
from calib.model import SystemModel
from drivers.clock import Clock
from drivers.errors import DeviceError

F64 = NDArray[np.float64]
#: the waits [s] between attempts to open a device unreachable at start (then the last, again)
DEVICE_RETRY_S = (1.0, 2.0, 5.0, 10.0, 30.0)


@dataclasses.dataclass
class InForce:
    """The parameters in force at start (`load_in_force`)."""

    model: SystemModel
    x: F64
    version: int
    recovered: tuple[int, int | None] | None = None  # an apply to complete: (version, cal_id)
    # (code, message, priority): raised once the loop runs
    start_alarms: list[tuple[str, str, str]] = dataclasses.field(default_factory=list)


def load_in_force(
    params: ParamsStore,
    store: Store,
    model: SystemModel,
    x0: F64,
    initial_residuals: Mapping[str, Any] | None,
    clock: Clock,
) -> InForce:
    """The parameters in force, as `model` (the [service] model) identifies them:
    `params/current.json` as the database's applied version (rebuilt from the history when
    damaged or missing; an apply the database does not know yet is completed at start), or x0
    applied as the initial version (with `initial_residuals`, Service's)."""
    applied = store.applied()
    last = int(applied[-1]["version"]) if applied else None
    try:
        current = params.current(model)
        damage = "missing" if current is None else ""
    except (InputError, OSError, ValueError, KeyError, TypeError) as exc:
        current, damage = None, f"damaged ({exc})"
    if current is None and last is None:  # a new state directory
        if isinstance(model, CompliantModel):
            # a rigid commissioning's vector, its temperature unknown here (the reference
            # temperature's; `rvis run --params` carries a file at its own)
            x0 = model.carried(x0)
        doc = plain_document(model, x0, INITIAL_SOURCE)
        if initial_residuals is not None:
            given = dict(initial_residuals)
            validation = given.pop("validation_errors_mm", None)
            cov = given.pop("covariance", None)
            doc |= {"residuals": given, "n_parameters": given.get("n_parameters")}
            if cov:  # the identification's, over its active parameters
                set_covariance(doc, list(cov["active"]), np.asarray(cov["cov"], float))
            if validation:  # the commissioning's workspace validation (app.line.accuracy)
                doc["validation"] = {"errors_mm": [float(e) for e in validation]}
        version = first_in_force(params, store, doc, "initial", clock)
        return InForce(model, x0.copy(), version)
    start_alarms: list[tuple[str, str, str]] = []
    if current is None:
        assert last is not None
        current = _rebuild_current(params, model, last, damage, start_alarms)
    version, model, x = current
    recovered = None
    if version != last:  # killed while applying: complete it at start
        doc = params.current_document() or {}
        cal_id = doc.get("calibration_id")
        recovered = (version, cal_id if isinstance(cal_id, int) else None)
    return InForce(model, x, version, recovered, start_alarms)


def _rebuild_current(
    params: ParamsStore,
    model: SystemModel,
    version: int,
    damage: str,
    start_alarms: list[tuple[str, str, str]],
) -> tuple[int, SystemModel, F64]:
    path = params.current_path
    try:
        params.rollback(version)
        current = params.current(model)
    except (InputError, OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(
            f"{damage}, and history version {version} (in force by the database) cannot"
            f" rebuild it: {exc}",
            file=path,
        ) from exc
    assert current is not None
    start_alarms.append(
        (
            AlarmCode.PARAMS_REBUILT,
            f"{path} was {damage}: rebuilt from history {version}",
            "high",
        )
    )
    return current


class Startup:
    """The start of the loop on the service `svc` (module docstring): the `start_alarms` of
    `load_in_force` raised, the devices opened, a fault held from before kept."""

    def __init__(
        self,
        svc: LineHost,
        operator: Operator,
        faults: Faults,
        decisions: Decisions,
        start_alarms: list[tuple[str, str, str]],
    ) -> None:
        self.svc = svc
        self.operator, self.faults, self.decisions = operator, faults, decisions
        self.start_alarms = start_alarms  # (code, message, priority): raised once it runs

    def run(self) -> None:
        svc = self.svc
        svc.bus.emit(
            "started", {"params_version": svc.version, "state_dir": str(svc.settings.state_dir)}
        )
        for code, message, priority in self.start_alarms:
            svc.alarm(code, message, priority)
        svc.decision.pending_calibration = svc.store.pending_calibration()
        if svc.decision.pending_calibration is not None and svc.applies_automatically():
            svc.apply_calibration(svc.decision.pending_calibration, None, "auto")  # killed before
        self.decisions.resubmit()
        self.faults.check_space()
        if not self._await_devices():
            return  # stopped while waiting for a device
        held = [a for a in svc.store.active_alarms() if a["code"] in FAULT_CODES]
        if held:
            self._hold_fault(held[0])
            return
        try:
            svc.watch.poll()
            home = svc.measurer.at_home()
        except DeviceError as exc:
            self.faults.device_fault(exc)
            return
        if not home:
            q = np.round(svc.station.robot.joints_deg(), 3).tolist()
            self.faults.enter_fault(
                AlarmCode.ROBOT_NOT_HOME, f"robot not at home at start (J = {q} deg)"
            )
            return
        svc.set_state(State.PAUSED if svc.decision.paused else State.IDLE)

    def _await_devices(self) -> bool:
        """Every device open (module docstring): at once, or after retries with back-off in
        FAULT with a `device_unreachable` alarm, the operator's commands answered meanwhile;
        False when stopped first."""
        svc = self.svc
        stale = svc.store.active_alarms(code=AlarmCode.DEVICE_UNREACHABLE)  # from a killed process
        if not svc.station.unreachable:
            self._clear_unreachable(bool(stale), None)
            return True
        if stale:
            svc.clear_alarms(AlarmCode.DEVICE_UNREACHABLE)
        errors = dict(svc.station.unreachable)
        for exc in errors.values():
            svc.note_device_error(exc)
        svc.fault.family = next(iter(errors))
        self.faults.enter_fault(AlarmCode.DEVICE_UNREACHABLE, self._unreachable_text(errors))
        attempts = 0
        while True:
            wait_s = DEVICE_RETRY_S[min(attempts, len(DEVICE_RETRY_S) - 1)]
            due = svc.clock.monotonic() + wait_s
            svc.fault.retry = {
                "attempts": attempts,
                "wait_s": wait_s,
                "next_utc": utc_text(svc.clock.time() + wait_s),
            }
            while (left := due - svc.clock.monotonic()) > 0 and not svc.stopping():
                svc.clock.wait(svc.wake, left)
                svc.wake.clear()
                svc.reraise_crash()
                self.operator.run_commands()
            if svc.stopping():
                return False
            attempts += 1
            errors = svc.station.open_unreachable()
            for exc in errors.values():
                svc.note_device_error(exc)
            if not errors:
                self._clear_unreachable(True, attempts)
                return True
            svc.fault.family = next(iter(errors))
            unreachable = {f: f"{type(e).__name__}: {e}" for f, e in errors.items()}
            svc.bus.emit("device_retry", {"attempts": attempts, "unreachable": unreachable})

    def _unreachable_text(self, errors: Mapping[str, DeviceError]) -> str:
        parts = [
            f"{f} ({self.svc.station.urls.get(f, '')}) unreachable: {type(e).__name__}: {e}"
            for f, e in errors.items()
        ]
        waits = ", ".join(f"{w:g}" for w in DEVICE_RETRY_S[:-1])
        return (
            f"{'; '.join(parts)}; the service tries again after {waits} s, then every"
            f" {DEVICE_RETRY_S[-1]:g} s, and leaves FAULT by itself once every device answers"
        )

    def _clear_unreachable(self, raised: bool, attempts: int | None) -> None:
        """Every device is open: the `device_unreachable` alarm (if any) cleared, the PLC's
        fault bit it set taken back, the fault's device forgotten."""
        svc = self.svc
        svc.fault.retry = None
        if not raised:
            return
        svc.clear_alarms(AlarmCode.DEVICE_UNREACHABLE)
        svc.fault.family = None
        with contextlib.suppress(DeviceError):
            svc.station.plc.set_signals(busy=False, done=False, fault=False)
        if attempts is not None:
            svc.bus.emit("devices_opened", {"attempts": attempts})

    def _hold_fault(self, alarm: dict[str, Any]) -> None:
        """Restarted with a fault alarm in force: stay in FAULT until an operator's reset."""
        svc = self.svc
        # the device of a held device fault failed in the process before: every device was
        # opened afresh since and answered, so none is shown at fault ("": none, not unknown)
        svc.fault.family = ""
        svc.set_state(State.FAULT)
        fault_stop(svc)
        svc.log.warning(
            "restarted in FAULT: alarm %s in force (%s)", alarm["code"], alarm["message"]
        )
