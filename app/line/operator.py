"""The operator's commands of the service (the control socket calls `request`): `Operator`,
a collaborator of app.line.service.Service that sees it as app.line.host.LineHost.

`status` and `subscribe` are answered at once from any thread; every other command is queued
and executed by the service loop between windows (`run_commands`; so a reply can wait for the
end of a running window), and written to the audit log (`actions` table) with the peer's uid,
its arguments, and whether it succeeded. A command the peer's role does not allow
(app/line/roles.py) is refused with the role it needs, and audited the same way.

    pause | resume | reset | recalibrate | approve [calibration] | reject [calibration]
    rollback version | ack alarm | shelve alarm reason [minutes]
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from queue import Empty, Queue
from typing import Any

from app.line.host import LineHost
from app.line.roles import NEEDS
from app.line.states import FAULT_CODES, State
from app.line.step import StepStatus
from app.line.store import StorageError
from drivers.errors import DeviceError

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


class CommandError(Exception):
    """A command that cannot be done now (the reply's `error`)."""


def _int(args: dict[str, Any], key: str) -> int:
    value = args.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise CommandError(f"'{key}' must be an integer")
    return value


class Operator:
    """The command queue and the handlers, on the service `svc`."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self._commands: Queue[tuple[str, dict[str, Any], int | None, str, Future[dict[str, Any]]]]
        self._commands = Queue()

    def request(
        self,
        cmd: str,
        args: dict[str, Any] | None = None,
        uid: int | None = None,
        groups: tuple[int, ...] | None = None,
    ) -> Future[dict[str, Any]]:
        """Queue a command; the future's result is the reply body ({"ok": ...}). A command
        the peer's role may not run is queued as refused: its audit row is written by the
        loop like any other's."""
        future: Future[dict[str, Any]] = Future()
        args = dict(args or {})
        if cmd not in COMMANDS or cmd == "subscribe":
            future.set_result({"ok": False, "error": f"unknown command {cmd!r}"})
        elif cmd == "status":
            future.set_result({"ok": True, **self.svc.status()})
        else:
            refusal = self.svc.roles.refusal(cmd, uid, groups)
            self._commands.put((cmd, args, uid, refusal, future))
            self.svc.wake.set()
        return future

    def cancel_queued(self, reason: str) -> None:
        """Answer every queued command with `reason` (nobody will execute them)."""
        while True:
            try:
                *_, future = self._commands.get_nowait()
            except Empty:
                return
            future.set_result({"ok": False, "error": reason})

    def run_commands(self) -> None:
        """Execute the queued commands (in the service loop, between windows)."""
        while True:
            try:
                cmd, args, uid, refusal, future = self._commands.get_nowait()
            except Empty:
                return
            reply: dict[str, Any] = {"ok": False, "error": "internal error"}
            try:
                reply = self._run_command(cmd, args, uid, refusal)
            finally:
                future.set_result(reply)

    def _run_command(
        self, cmd: str, args: dict[str, Any], uid: int | None, refusal: str = ""
    ) -> dict[str, Any]:
        """One command and its audit row (a storage failure fails the command, not the loop);
        a refused one is only audited."""
        svc = self.svc
        handler: Callable[[dict[str, Any], int | None], dict[str, Any]]
        handler = getattr(self, f"_cmd_{cmd}")
        reply: dict[str, Any]
        try:
            if refusal:
                reply = {"ok": False, "error": refusal, "role": NEEDS[cmd]}
            else:
                reply = {"ok": True, **handler(args, uid)}
        except CommandError as exc:
            reply = {"ok": False, "error": str(exc)}
        except StorageError as exc:
            reply = {"ok": False, "error": f"the state storage failed: {exc}"}
            svc.storage_fault(exc)
        detail = reply.get("error", "") or str(reply.get("message", ""))
        try:
            svc.store.add_action(svc.clock.time(), uid, cmd, args, bool(reply["ok"]), detail)
        except StorageError:
            svc.log.warning("audit of %s by uid %s not stored (state storage failing)", cmd, uid)
        svc.bus.emit("operator", {"cmd": cmd, "args": args, "uid": uid, "ok": reply["ok"]})
        return reply

    # -- handlers (run in the service loop, between windows) -------------------------------
    def _cmd_pause(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        svc.paused = True
        svc.save_state()
        if svc.state == State.IDLE:
            svc.set_state(State.PAUSED)
        return {"message": "paused", "state": svc.state.value}

    def _cmd_resume(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        svc.paused = False
        svc.save_state()
        if svc.state == State.PAUSED:
            svc.set_state(State.IDLE)
        return {"message": "resumed", "state": svc.state.value}

    def _cmd_reset(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        if svc.state != State.FAULT:
            raise CommandError(f"nothing to reset in state {svc.state.value}")
        if svc.station.unreachable:
            names = ", ".join(svc.station.unreachable)
            raise CommandError(
                f"{names} unreachable since the start: the service retries and leaves FAULT by"
                " itself when it answers (no reset needed)"
            )
        self._storage_back()
        try:
            svc.station.robot.reset()
            svc.station.plc.set_signals(busy=False, done=False, fault=False)
        except DeviceError as exc:
            svc.note_device_error(exc)
            raise CommandError(f"reset failed: {type(exc).__name__}: {exc}") from exc
        t = svc.clock.time()
        for code in FAULT_CODES:
            svc.store.clear_alarms(t, code)
        svc.set_state(State.PAUSED if svc.paused else State.IDLE)
        home = svc.measurer.at_home()
        note = "" if home else "; the robot comes home in the next window"
        return {"message": f"reset{note}", "state": svc.state.value}

    def _storage_back(self) -> None:
        """Before a reset: the alarms raised while the storage failed are stored now and the
        decision state is read back from the database (what was not committed never
        happened); CommandError while the storage still fails."""
        svc = self.svc
        if not svc.storage_failed:
            return
        try:
            svc.store.probe_write()
            with svc.store.batch():
                for a in svc.unstored_alarms:
                    svc.store.raise_alarm(a["t_raised"], a["code"], a["message"], a["priority"])
                svc.store.save_state(svc.clock.time(), svc.store.load_state() or svc.snapshot())
        except StorageError as exc:
            free = svc.paths.free_mb()
            raise CommandError(
                f"the state storage still fails ({exc}; {free:.0f} MB free under"
                f" {svc.paths.root}): free space or repair it, then reset again"
            ) from exc
        svc.unstored_alarms.clear()
        svc.storage_failed = False
        svc.restore()

    def _cmd_recalibrate(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        svc.force_recal = True
        svc.save_state()
        wait = svc.recal_wait()
        return {
            "message": f"recalibration requested: {wait or 'it starts now'}",
            "waits": bool(wait),
        }

    def _pending_id(self, args: dict[str, Any]) -> int:
        svc = self.svc
        cal_id = _int(args, "calibration") if "calibration" in args else svc.pending_calibration
        if cal_id is None or cal_id != svc.pending_calibration:
            raise CommandError(f"calibration {cal_id} is not pending")
        return cal_id

    def _cmd_approve(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        cal_id = self._pending_id(args)
        version = svc.apply_calibration(cal_id, uid, "approved")
        return {"message": f"calibration {cal_id} applied as version {version}", "version": version}

    def _cmd_reject(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        cal_id = self._pending_id(args)
        svc.store.decide_calibration(cal_id, "rejected", svc.clock.time(), uid)
        svc.pending_calibration = None
        if svc.step is not None and svc.step.status == StepStatus.PROPOSED:
            svc.step.move(StepStatus.ATTRIBUTING)  # its correction refused: the next one, with more
            svc.save_state()
        return {"message": f"calibration {cal_id} rejected"}

    def _cmd_rollback(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        version = _int(args, "version")
        if version not in svc.params.versions():
            raise CommandError(f"no parameters version {version}")
        svc.params.rollback(version)
        svc.in_force(version, None, "rollback", uid)
        return {"message": f"parameters version {version} in force", "version": version}

    def _cmd_ack(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        alarm_id = _int(args, "alarm")
        if not svc.store.ack_alarm(alarm_id, svc.clock.time(), uid):
            raise CommandError(f"no unacknowledged alarm {alarm_id}")
        return {"message": f"alarm {alarm_id} acknowledged"}

    def _cmd_shelve(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
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
