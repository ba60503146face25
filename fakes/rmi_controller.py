"""An asyncio FANUC RMI controller on loopback that moves a World's robot.

Speaks the subset of RMI the driver uses (drivers/rmi.py): FRC_Connect on the connect port names
the session port; commands FRC_Initialize, FRC_Abort, FRC_Reset, FRC_GetStatus,
FRC_ReadJointAngles, FRC_SetOverRide (``Value`` 1..100, kept across sessions like the controller's
general override); instruction FRC_JointMotionJRep (answered when the motion is done, after
max |dq| / (speed x override) x time_scale seconds of ``clock`` (real time by default), moving
the World's joints along the way; each motion's duration is appended to ``motion_durations_s``);
unsolicited
FRC_SystemFault and FRC_Terminate. Like the controller it refuses out-of-order SequenceIDs,
motion before FRC_Initialize, motion outside the joint limits and motion while an alarm is active
(until FRC_Reset).

Fault injection (one-shot, for the fault tests): ``fail_next(packet_name, mode)`` with mode
"drop" (close the connection on receipt), "mute" (never answer), "garble" (answer non-JSON),
"truncate" (half an answer, then close), "system_fault" (for a motion: start it, then raise an
alarm half-way), "disconnect" (for a motion: start it, then close every session half-way, as a
cable pulled mid-move), or an int ErrorID to answer with.

    with RmiController(world, time_scale=0.01) as ctrl:
        robot = RmiRobot("127.0.0.1", ctrl.port)
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from typing import Any

import numpy as np

from drivers.safety import JointLimits
from fakes._lineserver import LineServer
from fakes.clock import RealClock, SimClock
from fakes.world import World

RMIT_BASE = 2556928
ERR_NOT_INITIALIZED = RMIT_BASE + 3  # illustrative RMIT numbers: the fake's own
ERR_SEQUENCE = RMIT_BASE + 29
ERR_ALARM = RMIT_BASE + 14
ERR_LIMIT = RMIT_BASE + 17
ERR_UNKNOWN = RMIT_BASE + 2
ERR_VALUE = RMIT_BASE + 7
JOINTS = ("J1", "J2", "J3", "J4", "J5", "J6")


class RmiController(LineServer):
    """The fake controller; ``start()`` binds ephemeral ports on ``host``."""

    terminator = b"\r\n"

    def __init__(
        self,
        world: World,
        *,
        time_scale: float = 1.0,
        limits: JointLimits | None = None,
        clock: SimClock | None = None,
        **kw: Any,  # host, port: see LineServer
    ) -> None:
        super().__init__(**kw)
        self.world = world
        self.time_scale = float(time_scale)
        self.clock: SimClock = clock if clock is not None else RealClock()
        self.limits = limits or JointLimits.m710ic50()
        self.session_port = 0
        self.alarm = False
        self.override_pct = 100
        self.received: list[dict[str, Any]] = []
        self.motion_durations_s: list[float] = []
        self._initialized = False
        self._next_seq = 1
        self._motion: asyncio.Task[None] | None = None

    async def _start(self) -> None:
        await super()._start()
        self.session_port = await self._listen(0)

    # -- test controls (thread-safe) ----------------------------------------------------------
    def terminate_sessions(self) -> None:
        """Send FRC_Terminate to every session and close it (the controller's timeout)."""
        self._run(self._broadcast({"Communication": "FRC_Terminate"}, close=True))

    def raise_system_fault(self) -> None:
        self._run(self._system_fault())

    # -- protocol -----------------------------------------------------------------------------
    async def _handle(self, line: bytes, writer: asyncio.StreamWriter) -> bool:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            await self._send(writer, {"Communication": "FRC_Unknown", "ErrorID": ERR_UNKNOWN})
            return True
        self.received.append(msg)
        kind = next((k for k in ("Communication", "Command", "Instruction") if k in msg), "")
        name = str(msg.get(kind, ""))
        mode = self._faults.pop(name, None)
        keep = await self._transport_fault(mode, writer, truncated=b'{"Command": "' + name.encode())
        if keep is not None:
            return keep
        if isinstance(mode, int):
            await self._send(writer, {kind: name, "ErrorID": mode, **self._seq_of(msg)})
            return True
        if kind == "Instruction":
            half_way = mode if mode in ("system_fault", "disconnect") else None
            self._instruction(msg, writer, half_way=half_way)
            return True
        reply = self._reply(kind, name, msg)
        await self._send(writer, {kind: name, **reply})
        return name != "FRC_Disconnect"

    @staticmethod
    def _seq_of(msg: dict[str, Any]) -> dict[str, Any]:
        return {"SequenceID": msg["SequenceID"]} if "SequenceID" in msg else {}

    def _reply(self, kind: str, name: str, msg: dict[str, Any]) -> dict[str, Any]:
        if name == "FRC_Connect":
            return {
                "ErrorID": 0,
                "PortNumber": self.session_port,
                "MajorVersion": 1,
                "MinorVersion": 0,
            }
        if name == "FRC_Disconnect":
            return {"ErrorID": 0}
        if name == "FRC_GetStatus":
            return {
                "ErrorID": 0,
                "ServoReady": 0 if self.alarm else 1,
                "TPMode": 1,
                "RMIMotionStatus": 1 if self._initialized else 0,
                "ProgramStatus": 0,
                "SingleStepMode": 0,
                "NumberUTool": 10,
                "NextSequenceID": self._next_seq,
                "NumberUFrame": 9,
                "Override": self.override_pct,
            }
        if name == "FRC_ReadJointAngles":
            q = self.world.joints_deg()
            angles = {j: float(v) for j, v in zip(JOINTS, q, strict=True)}
            return {
                "ErrorID": 0,
                "TimeTag": 0,
                "Group": 1,
                "JointAngle": angles | {"J7": 0.0, "J8": 0.0, "J9": 0.0},
            }
        if name == "FRC_Initialize":
            if self.alarm:
                return {"ErrorID": ERR_ALARM, "GroupMask": 1}
            self._initialized, self._next_seq = True, 1
            return {"ErrorID": 0, "GroupMask": 1}
        if name == "FRC_Abort":
            self._stop_motion()
            self._initialized = False
            return {"ErrorID": 0}
        if name == "FRC_SetOverRide":
            value = msg.get("Value")
            if not (isinstance(value, int) and 1 <= value <= 100):
                return {"ErrorID": ERR_VALUE}
            self.override_pct = value
            return {"ErrorID": 0}
        if name == "FRC_Reset":
            self.alarm = False
            return {"ErrorID": 0}
        return {"ErrorID": ERR_UNKNOWN}

    def _instruction(
        self, msg: dict[str, Any], writer: asyncio.StreamWriter, *, half_way: str | None
    ) -> None:
        name, seq = msg.get("Instruction"), msg.get("SequenceID")
        error = self._check_instruction(msg)
        if error:
            self._spawn(
                self._send(writer, {"Instruction": name, "ErrorID": error, "SequenceID": seq})
            )
            return
        self._next_seq += 1
        target = np.array([float(msg["JointAngle"][j]) for j in JOINTS])
        previous = self._motion
        self._motion = self._spawn(
            self._run_motion(previous, target, float(msg["Speed"]), writer, seq, half_way)
        )

    def _check_instruction(self, msg: dict[str, Any]) -> int:
        if msg.get("Instruction") != "FRC_JointMotionJRep":
            return ERR_UNKNOWN
        if self.alarm:
            return ERR_ALARM
        if not self._initialized:
            return ERR_NOT_INITIALIZED
        if msg.get("SequenceID") != self._next_seq:
            return ERR_SEQUENCE
        try:
            q = np.array([float(msg["JointAngle"][j]) for j in JOINTS])
            speed = float(msg["Speed"])
        except (KeyError, TypeError, ValueError):
            return ERR_UNKNOWN
        inside = bool(self.limits.contains(q[None])[0])
        return 0 if inside and 0 < speed <= 100 else ERR_LIMIT

    async def _run_motion(
        self,
        previous: asyncio.Task[None] | None,
        target: np.ndarray,
        speed_pct: float,
        writer: asyncio.StreamWriter,
        seq: Any,
        half_way: str | None,
    ) -> None:
        if previous is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await previous
        start = self.world.joints_deg()
        speeds = np.asarray(self.limits.speed_deg_s) * speed_pct * self.override_pct / 1e4
        duration = float(np.max(np.abs(target - start) / speeds)) * self.time_scale
        self.motion_durations_s.append(duration)
        t0 = self.clock.monotonic()
        # the joints follow the clock (not a count of sleeps, whose overheads would add up)
        while (frac := (self.clock.monotonic() - t0) / duration if duration > 0 else 1.0) < 1.0:
            self.world.set_joints_deg(start + (target - start) * frac)
            if half_way is not None and frac >= 0.5:
                await self._half_way_fault(half_way)
                return
            left_real_s = (1.0 - frac) * duration / self.clock.scale
            await asyncio.sleep(min(0.01, left_real_s))
        if half_way is not None:  # a move too short to be seen half-way still fails
            await self._half_way_fault(half_way)
            return
        self.world.set_joints_deg(target)
        await self._send(
            writer, {"Instruction": "FRC_JointMotionJRep", "ErrorID": 0, "SequenceID": seq}
        )

    async def _half_way_fault(self, mode: str) -> None:
        if mode == "system_fault":
            await self._system_fault()
            return
        for writer in list(self._writers):  # "disconnect": the sessions vanish, no goodbye
            writer.close()

    async def _system_fault(self) -> None:
        self.alarm, self._initialized = True, False
        current = asyncio.current_task()
        if self._motion is not None and self._motion is not current:
            self._motion.cancel()
        await self._broadcast(
            {"Communication": "FRC_SystemFault", "SequenceID": self._next_seq - 1}
        )

    def _stop_motion(self) -> None:
        if self._motion is not None:
            self._motion.cancel()
            self._motion = None

    def _spawn(self, coro: Any) -> asyncio.Task[None]:
        return asyncio.get_running_loop().create_task(coro)

    async def _broadcast(self, msg: dict[str, Any], close: bool = False) -> None:
        for writer in list(self._writers):
            with contextlib.suppress(ConnectionError):
                await self._send(writer, msg)
            if close:
                writer.close()
