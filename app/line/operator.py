"""The operator's commands of the service (the control socket calls `request`).

`status` and `subscribe` are answered at once from any thread; every other command is queued
and executed by the service loop between windows (so a reply can wait for the end of a running
window), and written to the audit log (`actions` table) with the peer's uid, its arguments,
and whether it succeeded.

    pause | resume | reset | recalibrate | approve [calibration] | reject [calibration]
    rollback version | ack alarm | shelve alarm reason [minutes]
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from datetime import UTC, datetime
from queue import Empty, Queue
from typing import TYPE_CHECKING, Any

from calib.model import ALL_NAMES

#: alarms that hold the cell in FAULT until a reset (app.line.service imports them from here)
FAULT_CODES = ("device_fault", "robot_not_home", "internal_error", "state_storage")

if TYPE_CHECKING:
    from app.line.service import Service

MUTATING = (
    "pause",
    "resume",
    "reset",
    "recalibrate",
    "approve",
    "reject",
    "rollback",
    "ack",
    "shelve",
)
COMMANDS = ("status", "subscribe", *MUTATING)
SUSPECTS_IN_STATUS = 5  # the status reply's last suspect intervals


def utc_text(t: float) -> str:
    """ISO 8601 UTC of a clock time (seconds since the epoch)."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="seconds")


def alarm_status(a: dict[str, Any]) -> dict[str, Any]:
    """An alarm as the status reply carries it (the message also as `text`)."""
    out = {k: a[k] for k in ("id", "code", "priority", "message", "state")}
    out["text"] = a["message"]
    out["raised_utc"] = utc_text(a["t_raised"])
    return out


def _calibration(svc: Service, cal_id: int) -> dict[str, Any] | None:
    return svc.store.calibration(cal_id)


def device_of(exc: BaseException, devices: Mapping[str, object]) -> str | None:
    """The family of the device that raised `exc` (the stamp a device's public method puts on
    its errors, drivers.errors; or its cause's), when it is one of `devices`; else None."""
    seen: BaseException | None = exc
    while seen is not None:
        family = getattr(seen, "family", None)
        if isinstance(family, str) and family in devices:
            return family
        seen = seen.__cause__
    return None


class CommandError(Exception):
    """A command that cannot be done now (the reply's `error`)."""


def _int(args: dict[str, Any], key: str) -> int:
    value = args.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise CommandError(f"'{key}' must be an integer")
    return value


class OperatorCommands:
    """Mixin of Service: the command queue and the handlers."""

    _commands: Queue[tuple[str, dict[str, Any], int | None, Future[dict[str, Any]]]]
    _wake: threading.Event
    #: the device family of the fault in force (None: unknown)
    _fault_family: str | None = None

    @property
    def device_errors(self) -> dict[str, dict[str, str]]:
        """Per device family: the last error the service saw from it ({"error", "utc"})."""
        errors: dict[str, dict[str, str]] = self.__dict__.setdefault("_device_errors", {})
        return errors

    def note_device_error(self, exc: BaseException) -> str | None:
        """Keep `exc` as the last error of the device it came from (the status reply's
        `devices`); returns that device's family (None: not attributable to one)."""
        svc: Service = self  # type: ignore[assignment]
        family = device_of(exc, svc.station.devices())
        if family is not None:
            self.device_errors[family] = {
                "error": f"{type(exc).__name__}: {exc}",
                "utc": utc_text(svc.clock.time()),
            }
        return family

    def request(
        self, cmd: str, args: dict[str, Any] | None = None, uid: int | None = None
    ) -> Future[dict[str, Any]]:
        """Queue a command; the future's result is the reply body ({"ok": ...})."""
        future: Future[dict[str, Any]] = Future()
        args = dict(args or {})
        if cmd not in COMMANDS or cmd == "subscribe":
            future.set_result({"ok": False, "error": f"unknown command {cmd!r}"})
        elif cmd == "status":
            future.set_result({"ok": True, **self.status()})
        else:
            self._commands.put((cmd, args, uid, future))
            self._wake.set()
        return future

    def status(self) -> dict[str, Any]:
        """The status reply; answered even when the state storage fails (what could not be
        read is left out and `storage_error` says why)."""
        from app.line.store import StorageError

        svc: Service = self  # type: ignore[assignment]
        try:
            return self._status()
        except StorageError as exc:
            return {
                "state": svc.state.value,
                "paused": svc.paused,
                "params_version": svc.version,
                "counters": dict(svc.counters),
                "alarms": [alarm_status(a) for a in svc._unstored_alarms],
                "step": self._step_text(),
                "storage_error": str(exc),
            }

    def _status(self) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        w = svc.watch
        return {
            "state": svc.state.value,
            "paused": svc.paused,
            "params_version": svc.version,
            "pending_calibration": svc.pending_calibration,
            "recalibrating": svc.recalibrator.busy,
            "mode": svc.settings.recalib.mode,
            "counters": dict(svc.counters),
            "measurements": svc.store.counts(),
            "schedule": {"position": svc.store.schedule_position()[0], "slots": len(svc.schedule)},
            "plc": None
            if w.inputs is None
            else {
                "window_open": w.inputs.window_open,
                "line_running": w.inputs.line_running,
                "heartbeat_alive": w.alive,
            },
            "window": self._window_status(),
            "calibration": self._calibration_status(),
            "alarms": [alarm_status(a) for a in svc.store.active_alarms() + svc._unstored_alarms],
            "cell_temp_c": svc.cell_temp_c,
            "drift": svc.drift.state(),
            "drift_change": svc.drift.change_state(),
            "step": self._step_text(),
            "devices": self._device_status(),
            "pending": self._pending_status(),
            "now_utc": utc_text(svc.clock.time()),  # the service's clock (sim: ahead)
            "flagged_step": None if svc.step is None else svc.step.to_json(),
            "suspect_intervals": self._suspect_status(),
        }

    def _suspect_status(self) -> list[dict[str, Any]]:
        """The last suspect intervals (app.line.step), oldest first: when the calibration in
        force was wrong after a step, with its size; the open one has no end yet."""
        from app.line.step_service import suspect_json

        svc: Service = self  # type: ignore[assignment]
        return [suspect_json(r) for r in svc.store.suspects(last=SUSPECTS_IN_STATUS)]

    def _step_text(self) -> str:
        """What the service is doing, in a few words (the TUI's status line)."""
        svc: Service = self  # type: ignore[assignment]
        if svc.recalibrator.busy:
            return "recalibrating"
        steps = {
            "MEASURING": "measuring in the window",
            "IDLE": "waiting for a window",
            "PAUSED": "paused by the operator",
            "FAULT": "stopped on a fault, reset needed",
        }
        return steps.get(svc.state.name, svc.state.value.lower())

    def _device_status(self) -> dict[str, dict[str, Any]]:
        """Per device family: the URL it was opened with, its state (closed; fault: the
        device of the fault in force, or every device when that one is unknown; the PLC
        without heartbeat; ok), and the last error the service saw from it with its time
        (kept after a reset)."""
        svc: Service = self  # type: ignore[assignment]
        faulted = bool(svc.store.active_alarms(code="device_fault"))
        errors = self.device_errors
        out = {}
        for family, device in svc.station.devices().items():
            state = "ok"
            if not device.is_open:
                state = "closed"
            elif faulted and self._fault_family in (None, family):
                state = "fault"
            elif family == "plc" and svc.watch.lost:
                state = "no heartbeat"
            last = errors.get(family, {})
            out[family] = {
                "url": svc.station.urls.get(family, ""),
                "state": state,
                "last_error": last.get("error"),
                "last_error_utc": last.get("utc"),
            }
        return out

    def _calibration_status(self) -> dict[str, Any]:
        """The parameters in force: version, when applied (UTC), the fit's RMS if identified."""
        svc: Service = self  # type: ignore[assignment]
        applied = [a for a in svc.store.applied() if a["version"] == svc.version]
        last = applied[-1] if applied else None
        rms = None
        if last is not None and last["calibration_id"] is not None:
            cal = _calibration(svc, int(last["calibration_id"]))
            rms = None if cal is None else cal["rms_mm"]
        return {
            "version": svc.version,
            "pending": svc.pending_calibration,
            "applied_utc": None if last is None else utc_text(last["t"]),
            "rms_mm": rms,
        }

    def _pending_status(self) -> dict[str, Any] | None:
        """The calibration waiting for approval: fit, gates and each parameter's change."""
        svc: Service = self  # type: ignore[assignment]
        cal_id = svc.pending_calibration
        cal = None if cal_id is None else _calibration(svc, cal_id)
        if cal is None:
            return None
        current = dict(zip(ALL_NAMES, (float(v) for v in svc.x), strict=True))
        params = (cal.get("document") or {}).get("parameters", [])
        return {
            "id": cal_id,
            "rms_mm": cal["rms_mm"],
            "holdout_rms_mm": cal["holdout_rms_mm"],
            "current_holdout_rms_mm": cal["current_holdout_rms_mm"],
            "gates": {"passed": not cal["gates"], "failures": list(cal["gates"])},
            "parameters": [
                {
                    "name": p["name"],
                    "unit": p.get("unit", ""),
                    "current": current.get(p["name"]),
                    "value": p.get("value"),
                    "std": p.get("std"),
                }
                for p in params
                if p.get("identified", True)
            ],
        }

    def _window_status(self) -> dict[str, Any]:
        """The line as the TUI shows it: window open and the time left, line, heartbeat."""
        svc: Service = self  # type: ignore[assignment]
        w = svc.watch
        i = w.inputs
        is_open = bool(i is not None and i.window_open)
        return {
            "open": is_open,
            "remaining_s": w.remaining_s() if is_open and w.opened_t is not None else None,
            "line_running": bool(i is not None and i.line_running),
            "heartbeat_alive": w.alive,
        }

    def _run_commands(self) -> None:
        while True:
            try:
                cmd, args, uid, future = self._commands.get_nowait()
            except Empty:
                return
            reply: dict[str, Any] = {"ok": False, "error": "internal error"}
            try:
                reply = self._run_command(cmd, args, uid)
            finally:
                future.set_result(reply)

    def _run_command(self, cmd: str, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        """One command and its audit row (a storage failure fails the command, not the loop)."""
        from app.line.store import StorageError

        svc: Service = self  # type: ignore[assignment]
        handler: Callable[[dict[str, Any], int | None], dict[str, Any]]
        handler = getattr(self, f"_cmd_{cmd}")
        try:
            reply = {"ok": True, **handler(args, uid)}
        except CommandError as exc:
            reply = {"ok": False, "error": str(exc)}
        except StorageError as exc:
            reply = {"ok": False, "error": f"the state storage failed: {exc}"}
            svc._storage_fault(exc)
        detail = reply.get("error", "") or str(reply.get("message", ""))
        try:
            svc.store.add_action(svc.clock.time(), uid, cmd, args, bool(reply["ok"]), detail)
        except StorageError:
            svc.log.warning("audit of %s by uid %s not stored (state storage failing)", cmd, uid)
        svc.bus.emit("operator", {"cmd": cmd, "args": args, "uid": uid, "ok": reply["ok"]})
        return reply

    # -- handlers (run in the service loop, between windows) -------------------------------
    def _cmd_pause(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        from app.line.service import State

        svc: Service = self  # type: ignore[assignment]
        svc.paused = True
        svc._save_state()
        if svc.state == State.IDLE:
            svc._set_state(State.PAUSED)
        return {"message": "paused", "state": svc.state.value}

    def _cmd_resume(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        from app.line.service import State

        svc: Service = self  # type: ignore[assignment]
        svc.paused = False
        svc._save_state()
        if svc.state == State.PAUSED:
            svc._set_state(State.IDLE)
        return {"message": "resumed", "state": svc.state.value}

    def _cmd_reset(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        from app.line.service import State
        from drivers.errors import DeviceError

        svc: Service = self  # type: ignore[assignment]
        if svc.state != State.FAULT:
            raise CommandError(f"nothing to reset in state {svc.state.value}")
        self._storage_back()
        try:
            svc.station.robot.reset()
            svc.station.plc.set_signals(busy=False, done=False, fault=False)
        except DeviceError as exc:
            self.note_device_error(exc)
            raise CommandError(f"reset failed: {type(exc).__name__}: {exc}") from exc
        t = svc.clock.time()
        for code in FAULT_CODES:
            svc.store.clear_alarms(t, code)
        svc._set_state(State.PAUSED if svc.paused else State.IDLE)
        home = svc.measurer.at_home()
        note = "" if home else "; the robot comes home in the next window"
        return {"message": f"reset{note}", "state": svc.state.value}

    def _storage_back(self) -> None:
        """Before a reset: the alarms raised while the storage failed are stored now and the
        decision state is read back from the database (what was not committed never
        happened); CommandError while the storage still fails."""
        from app.line.store import StorageError

        svc: Service = self  # type: ignore[assignment]
        if not svc.storage_failed:
            return
        try:
            svc.store.probe_write()
            with svc.store.batch():
                for a in svc._unstored_alarms:
                    svc.store.raise_alarm(a["t_raised"], a["code"], a["message"], a["priority"])
                svc.store.save_state(svc.clock.time(), svc.store.load_state() or svc._snapshot())
        except StorageError as exc:
            free = svc.paths.free_mb()
            raise CommandError(
                f"the state storage still fails ({exc}; {free:.0f} MB free under"
                f" {svc.paths.root}): free space or repair it, then reset again"
            ) from exc
        svc._unstored_alarms.clear()
        svc.storage_failed = False
        svc._restore()

    def _cmd_recalibrate(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        svc.force_recal = True
        svc._save_state()
        return {"message": "recalibration requested"}

    def _pending_id(self, args: dict[str, Any]) -> int:
        svc: Service = self  # type: ignore[assignment]
        cal_id = _int(args, "calibration") if "calibration" in args else svc.pending_calibration
        if cal_id is None or cal_id != svc.pending_calibration:
            raise CommandError(f"calibration {cal_id} is not pending")
        return cal_id

    def _cmd_approve(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        cal_id = self._pending_id(args)
        version = svc._apply_calibration(cal_id, uid, "approved")
        return {"message": f"calibration {cal_id} applied as version {version}", "version": version}

    def _cmd_reject(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        cal_id = self._pending_id(args)
        svc.store.decide_calibration(cal_id, "rejected", svc.clock.time(), uid)
        svc.pending_calibration = None
        if svc.step is not None and svc.step.status == "proposed":
            svc.step.status = "attributing"  # its correction refused: the next one, with more
            svc._save_state()
        return {"message": f"calibration {cal_id} rejected"}

    def _cmd_rollback(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        version = _int(args, "version")
        if version not in svc.params.versions():
            raise CommandError(f"no parameters version {version}")
        svc.params.rollback(version)
        svc._in_force(version, None, "rollback", uid)
        return {"message": f"parameters version {version} in force", "version": version}

    def _cmd_ack(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        alarm_id = _int(args, "alarm")
        if not svc.store.ack_alarm(alarm_id, svc.clock.time(), uid):
            raise CommandError(f"no raised alarm {alarm_id}")
        return {"message": f"alarm {alarm_id} acknowledged"}

    def _cmd_shelve(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc: Service = self  # type: ignore[assignment]
        alarm_id = _int(args, "alarm")
        reason = args.get("reason")
        if not isinstance(reason, str) or not reason.strip():
            raise CommandError("shelving needs a 'reason'")
        minutes = args.get("minutes", 60)
        if isinstance(minutes, bool) or not isinstance(minutes, int | float) or minutes <= 0:
            raise CommandError("'minutes' must be a positive number")
        until = svc.clock.time() + 60.0 * float(minutes)
        if not svc.store.shelve_alarm(alarm_id, until, reason):
            raise CommandError(f"no active alarm {alarm_id}")
        return {"message": f"alarm {alarm_id} shelved for {minutes:g} min"}
