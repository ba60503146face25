"""The service's alarms and faults: `Faults`, a collaborator of app.line.service.Service that
sees it as app.line.host.LineHost (as app.line.operator's commands do).

An alarm is stored, or kept in memory while the state storage fails (the service's
`fault.unstored_alarms`, app.line.fault_record: a negative id), and each change is one event
carrying the alarm (app.line.states.alarm_event). FAULT stops the robot, sets the PLC's fault
bit and raises an urgent alarm, each best effort: a device's error (the alarm names the device
and its URL when the error is one device's), a storage failure (`state_storage`, nothing
acknowledged that was not committed) or whatever the caller names. The free space under the
state directory is looked at once a minute (`low_disk`).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Mapping
from typing import Any

from app.line.host import LineHost
from app.line.states import AlarmCode, State, utc_text
from app.line.status import device_of
from app.line.store import StorageError

SPACE_CHECK_S = 60.0  # how often the free space under the state directory is looked at


class Faults:
    """Alarms raised and cleared, FAULT entered, device errors noted, on the service `svc`."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self._space_check_t = -float("inf")

    def alarm(
        self,
        code: str,
        message: str,
        priority: str = "high",
        detail: Mapping[str, Any] | None = None,
    ) -> int:
        """Raise an alarm (stored; kept in memory while the storage fails); its id. The event
        carries its state as stored: `shelved` (with the reason and until when) while its code
        is shelved (ISA-18.2 shelves the alarm, app.line.store.Store.raise_alarm); `detail`:
        its structured fields beside the text (app.line.states.alarm_detail)."""
        svc = self.svc
        t = svc.clock.time()
        try:
            alarm_id = svc.store.raise_alarm(t, code, message, priority, detail)
        except StorageError:
            alarm_id = self._unstored_alarm(code, message, priority, detail)
        row = None
        if alarm_id > 0:  # stored
            with contextlib.suppress(StorageError):
                row = svc.store.alarm(alarm_id)
        data: dict[str, Any] = {
            "id": alarm_id,
            "code": code,
            "message": message,
            "priority": priority,
        }
        if detail:
            data["detail"] = dict(detail)
        data["state"] = "raised" if row is None else str(row["state"])
        if data["state"] == "shelved" and row is not None:
            data.update(reason=row["shelve_reason"], until_utc=utc_text(row["shelved_until"]))
        svc.bus.emit("alarm", data, level=logging.WARNING, t=t)
        return alarm_id

    def clear_alarms(self, code: str, t: float | None = None) -> int:
        """Clear the active alarms of `code`, each an `alarm_cleared` event with its id (OPC
        UA: that occurrence of the condition ends), written with it by the store's one writer
        of a clearing (app.line.log_store.LogRecords.clear_alarms, which a maintenance
        procedure's hand-over uses too) and then logged and streamed; how many."""
        svc = self.svc
        t = svc.clock.time() if t is None else t
        events = svc.store.clear_alarms(t, code)  # the rows and their events, one transaction
        for data in events:
            svc.bus.publish("alarm_cleared", data, t=t)
        return len(events)

    def _unstored_alarm(
        self, code: str, message: str, priority: str, detail: Mapping[str, Any] | None
    ) -> int:
        unstored = self.svc.fault.unstored_alarms
        for a in unstored:
            if a["code"] == code:
                return int(a["id"])
        alarm_id = -(len(unstored) + 1)  # negative: not in the database (yet)
        unstored.append(
            {
                "id": alarm_id,
                "code": code,
                "priority": priority,
                "message": message,
                "state": "raised",
                "t_raised": self.svc.clock.time(),
                "detail": None if detail is None else dict(detail),
            }
        )
        return alarm_id

    def storage_fault(self, exc: StorageError) -> None:
        """The state storage failed: FAULT with the robot stopped, nothing acknowledged."""
        svc = self.svc
        if svc.state == State.FAULT and svc.fault.storage_failed:
            return
        svc.fault.storage_failed = True
        free = svc.paths.free_mb()
        svc.log.error("state storage failed: %s", exc, extra={"event": "state_storage"})
        self.enter_fault(
            AlarmCode.STATE_STORAGE,
            f"state storage failed ({exc}; {free:.0f} MB free under {svc.paths.root}): the"
            " measurement was not acknowledged; free space or repair, then reset",
        )

    def check_space(self) -> None:
        """A `low_disk` alarm while the free space is below [service] min_free_mb."""
        svc = self.svc
        now = svc.clock.monotonic()
        if now - self._space_check_t < SPACE_CHECK_S:
            return
        self._space_check_t = now
        free, floor = svc.paths.free_mb(), svc.settings.ops.min_free_mb
        active = svc.store.active_alarms(code=AlarmCode.LOW_DISK)
        if free < floor and not active:
            self.alarm(
                AlarmCode.LOW_DISK,
                f"{free:.0f} MB free under {svc.paths.root} (below [service] min_free_mb ="
                f" {floor:g}): free space before the state storage fills",
                "medium",
            )
        elif free >= floor and active:
            self.clear_alarms(AlarmCode.LOW_DISK)

    def note_device_error(self, exc: BaseException) -> str | None:
        """Keep `exc` as the last error of the device it came from (the status reply's
        `devices`); returns that device's family (None: not attributable to one)."""
        svc = self.svc
        family = device_of(exc, svc.station.devices())
        if family is not None:
            svc.fault.device_errors[family] = {
                "error": f"{type(exc).__name__}: {exc}",
                "utc": utc_text(svc.clock.time()),
            }
        return family

    def device_fault(self, exc: BaseException) -> None:
        """FAULT on a device's error; the alarm names the device and its URL when the error
        is one device's (`plc (plc+modbus://...): DeviceConnectionError: ...`)."""
        svc = self.svc
        family = svc.fault.family = self.note_device_error(exc)
        where = "" if family is None else f"{family} ({svc.station.urls.get(family, '')}): "
        self.enter_fault(AlarmCode.DEVICE_FAULT, f"{where}{type(exc).__name__}: {exc}")

    def enter_fault(self, code: str, message: str, detail: Mapping[str, Any] | None = None) -> None:
        """FAULT: stop the robot, set the PLC fault bit, raise the alarm (each best effort)."""
        svc = self.svc
        svc.set_state(State.FAULT)
        fault_stop(svc)
        self.alarm(code, message, "urgent", detail)


def fault_stop(svc: LineHost) -> None:
    """FAULT's stop: the robot stopped and the PLC's fault bit set, each best effort."""
    with contextlib.suppress(Exception):
        svc.station.robot.abort()
    with contextlib.suppress(Exception):
        svc.station.plc.set_signals(busy=False, done=False, fault=True)
