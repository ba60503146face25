"""The operator's commands of the service (the control socket calls `request`): `Operator`,
a collaborator of app.line.service.Service that sees it as app.line.host.LineHost.

`status` and `subscribe` are answered at once from any thread; every other command is queued
and executed by the service loop between windows (`run_commands`; so a reply can wait for the
end of a running window), and written to the audit log (`actions` table) with the peer's uid,
its arguments, and whether it succeeded. The commands are app/line/roles.py's table (`NEEDS`),
one handler `_cmd_<name>` each: a command the table does not name is unknown, one the peer's
role does not allow is refused with the role it needs, and audited the same way.

    pause | resume | reset | recalibrate | approve [calibration] | reject [calibration]
    rollback version | ack alarm | shelve alarm reason [minutes]

A rollback to the version in force is refused (nothing would change but the history). A
rollback in auto mode holds automatic applies (`svc.decision.auto_hold`, in the decision state): a
calibration that passes its gates waits as in approve mode, until an engineer approves one or
resumes (`LIFTS_HOLD`; an operator's resume only resumes measuring); the reply and the status
say so.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from queue import Empty, Queue
from typing import Any

from app.line.host import LineHost
from app.line.roles import ENGINEER, LIFTS_HOLD, NEEDS
from app.line.states import FAULT_CODES, HOLD_LIFT, State, alarm_event, utc_text
from app.line.store import StorageError
from drivers.errors import DeviceError

Reply = dict[str, Any]


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
        self._commands: Queue[tuple[str, dict[str, Any], int | None, str, str, Future[Reply]]]
        self._commands = Queue()
        self.role = ENGINEER  # the role of the peer whose command runs now (`_run_command`)

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
        if cmd not in NEEDS or cmd == "subscribe":  # subscribe: the socket streams events
            future.set_result({"ok": False, "error": f"unknown command {cmd!r}"})
        elif cmd == "status":
            future.set_result({"ok": True, **self.svc.status()})
        else:
            role = self.svc.roles.role(uid, groups)
            refusal = self.svc.roles.refusal(cmd, uid, groups)
            self._commands.put((cmd, args, uid, role, refusal, future))
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
                cmd, args, uid, role, refusal, future = self._commands.get_nowait()
            except Empty:
                return
            reply: dict[str, Any] = {"ok": False, "error": "internal error"}
            try:
                reply = self._run_command(cmd, args, uid, refusal, role)
            finally:
                future.set_result(reply)

    def _run_command(
        self, cmd: str, args: dict[str, Any], uid: int | None, refusal: str, role: str
    ) -> dict[str, Any]:
        """One command and its audit row (a storage failure fails the command, not the loop);
        a refused one is only audited."""
        svc = self.svc
        handler: Callable[[dict[str, Any], int | None], dict[str, Any]]
        reply: dict[str, Any]
        try:
            if refusal:
                reply = {"ok": False, "error": refusal, "role": NEEDS.get(cmd, "")}
            else:
                handler = getattr(self, f"_cmd_{cmd}")
                self.role = role
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
        svc.decision.paused = True
        svc.save_state()
        if svc.state == State.IDLE:
            svc.set_state(State.PAUSED)
        return {"message": "paused", "state": svc.state.value}

    def _cmd_resume(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        """Measure again; an engineer's resume also lifts the hold of a rollback (when no
        calibration waits for a decision: that one is approved or rejected first)."""
        svc = self.svc
        hold, note = svc.decision.auto_hold, ""
        if hold is not None:
            pending = svc.decision.pending_calibration
            if self.role != LIFTS_HOLD:
                note = f"; {HOLD_LIFT} (uid {uid} is an {self.role})"
            elif pending is not None:
                note = f"; automatic applies stay held: approve or reject calibration {pending}"
            else:
                svc.decision.auto_hold = None
                note = "; automatic applies go on (the hold of the rollback lifted)"
        svc.decision.paused = False
        svc.save_state()
        if svc.state == State.PAUSED:
            svc.set_state(State.IDLE)
        return {
            "message": f"resumed{note}",
            "state": svc.state.value,
            "held": bool(svc.decision.auto_hold),
        }

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
        self._reopen_lost()
        try:
            svc.station.robot.reset()
            svc.station.plc.set_signals(busy=False, done=False, fault=False)
        except DeviceError as exc:
            svc.note_device_error(exc)
            raise CommandError(f"reset failed: {type(exc).__name__}: {exc}") from exc
        t = svc.clock.time()
        for code in FAULT_CODES:
            svc.clear_alarms(code, t)
        svc.set_state(State.PAUSED if svc.decision.paused else State.IDLE)
        home = svc.measurer.at_home()
        note = "" if home else "; the robot comes home in the next window"
        return {"message": f"reset{note}", "state": svc.state.value}

    def _reopen_lost(self) -> None:
        """Before a reset: a device lost while running (a camera switched off and on) is opened
        again; CommandError naming it while it does not open (the robot is not sent out to
        fault on it again)."""
        svc = self.svc
        failed = svc.station.reopen_lost()
        if not failed:
            return
        for exc in failed.values():
            svc.note_device_error(exc)
        family, exc = next(iter(failed.items()))
        raise CommandError(
            f"{family} ({svc.station.urls.get(family, '')}) was lost and does not open again"
            f" ({type(exc).__name__}: {exc}): reset again once it answers; a restart is needed"
            " if it still does not"
        )

    def _storage_back(self) -> None:
        """Before a reset: the alarms raised while the storage failed are stored now and the
        decision state is read back from the database (what was not committed never
        happened); CommandError while the storage still fails."""
        svc = self.svc
        if not svc.fault.storage_failed:
            return
        try:
            svc.store.probe_write()
            with svc.store.batch():
                for a in svc.fault.unstored_alarms:
                    svc.store.raise_alarm(
                        a["t_raised"], a["code"], a["message"], a["priority"], a.get("detail")
                    )
                svc.store.save_state(svc.clock.time(), svc.store.load_state() or svc.snapshot())
        except StorageError as exc:
            free = svc.paths.free_mb()
            raise CommandError(
                f"the state storage still fails ({exc}; {free:.0f} MB free under"
                f" {svc.paths.root}): free space or repair it, then reset again"
            ) from exc
        svc.fault.stored_again()
        svc.restore()

    def _cmd_recalibrate(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        svc.decision.force_recal = True
        svc.save_state()
        wait = svc.recal_wait()
        return {
            "message": f"recalibration requested: {wait or 'it starts now'}",
            "waits": bool(wait),
        }

    def _pending_id(self, args: dict[str, Any]) -> int:
        svc = self.svc
        pending = svc.decision.pending_calibration
        if pending is None:
            raise CommandError("no calibration is pending: nothing to approve or reject")
        cal_id = _int(args, "calibration") if "calibration" in args else pending
        if cal_id != pending:
            raise CommandError(f"calibration {cal_id} is not pending (calibration {pending} is)")
        return cal_id

    def _cmd_approve(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        cal_id = self._pending_id(args)
        held, svc.decision.auto_hold = (
            svc.decision.auto_hold,
            None,
        )  # approved: automatic applies go on
        try:
            version = svc.apply_calibration(cal_id, uid, "approved")
        except Exception:
            svc.decision.auto_hold = held
            raise
        note = "; automatic applies go on (the hold of the rollback lifted)" if held else ""
        return {
            "message": f"calibration {cal_id} applied as version {version}{note}",
            "version": version,
        }

    def _cmd_reject(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        cal_id = self._pending_id(args)
        svc.store.decide_calibration(cal_id, "rejected", svc.clock.time(), uid)
        svc.decision.pending_calibration = None
        return {"message": f"calibration {cal_id} rejected"}

    def _cmd_rollback(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        version = _int(args, "version")
        if version == svc.version:
            raise CommandError(
                f"parameters version {version} is in force already: nothing to roll back"
            )
        if version not in svc.params.versions():
            raise CommandError(f"no parameters version {version}")
        svc.params.rollback(version)
        if svc.settings.recalib.mode == "auto":  # saved with the apply (in_force)
            t = utc_text(svc.clock.time())
            svc.decision.auto_hold = {"version": version, "uid": uid, "since_utc": t}
        svc.in_force(version, None, "rollback", uid)
        note = f"; {HOLD_LIFT}" if svc.decision.auto_hold is not None else ""
        return {
            "message": f"parameters version {version} in force{note}",
            "version": version,
            "held": svc.decision.auto_hold is not None,
        }

    def _cmd_ack(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
        svc = self.svc
        alarm_id = _int(args, "alarm")
        t = svc.clock.time()
        if not svc.store.ack_alarm(alarm_id, t, uid):
            raise CommandError(f"no unacknowledged alarm {alarm_id}")
        row = svc.store.alarm(alarm_id)
        if row is not None:  # the comment and who: OPC UA's Comment and ClientUserId
            who = str(args.get("user", "")) or ("" if uid is None else f"uid {uid}")
            more = {"comment": str(args.get("comment", "")), "user": who}
            svc.bus.emit("alarm_acked", alarm_event(row, str(row["state"]), **more), t=t)
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
        t = svc.clock.time()
        until = t + 60.0 * float(minutes)
        if not svc.store.shelve_alarm(alarm_id, until, reason):
            raise CommandError(f"no active alarm {alarm_id}")
        row = svc.store.alarm(alarm_id)
        if row is not None:
            data = alarm_event(row, "shelved", reason=reason, until_utc=utc_text(until))
            svc.bus.emit("alarm_shelved", data, t=t)
        return {"message": f"alarm {alarm_id} shelved for {minutes:g} min"}
