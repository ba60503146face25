"""An asyncio FANUC RMI controller on loopback that moves a World's robot, as strict as the RMI
manual (B-84184EN): packet names, fields, ErrorID numbers (drivers/rmi_errors.py) and forms.

FRC_Connect on the connect port names the session port. Commands: FRC_Initialize (refused while
RMI already runs, error 7015, and with an alarm active, RMIT-007), FRC_Abort (RMIT-014 when RMI is
not running), FRC_Reset, FRC_GetStatus, FRC_ReadError, FRC_ReadJointAngles,
FRC_ReadCartesianPosition (needs ``pose_of``, the forward kinematics the wiring hands in; RMIT-001
without it), FRC_SetUFrameUTool / FRC_GetUFrameUTool (UFrame 0..9, UTool 1..10), FRC_SetOverRide
(``Value`` 1..100, RMIT-005 otherwise; kept across sessions like the controller's general
override). Instructions, executed one after the other and answered when done: FRC_JointMotionJRep,
FRC_JointRelativeJRep (SpeedType "Percent", Speed 1..100, TermType FINE/CNT/CR; a motion takes max
|dq| / (speed x override) x time_scale seconds, more with ``accel_s`` (each joint's time to its
speed: a trapezoid) and ``settle_s`` (at a FINE stop) when given (the simulated line's robot:
fakes/line.py), moving the World's joints along the way; each
duration is appended to ``motion_durations_s``; time follows ``clock``, real time by
default: on a VirtualClock the motion's duration passes on the clock, off the event loop so
that an FRC_Abort sent meanwhile is served, and the joints are set where the motion is when it
ends or is stopped), FRC_WaitTime, FRC_SetUFrame, FRC_SetUTool.
Like the controller it refuses out-of-order SequenceIDs (RMIT-029), instructions before
FRC_Initialize (RMIT-009), motion outside the joint limits (RMIT-036) and anything while an alarm
is active (RMIT-007, until FRC_Reset). Bad JSON and unknown packets are answered with the
manual's unknown-packet form ``{"Command": "Unknown", "ErrorID": N}`` (RMIT-013 for a command,
RMIT-020 for an instruction, with its SequenceID). Unsolicited: FRC_SystemFault, FRC_Terminate.

Fault injection (one-shot, for the fault tests): ``fail_next(packet_name, mode)`` with mode
"drop" (close the connection on receipt), "mute" (never answer), "garble" (answer non-JSON),
"truncate" (half an answer, then close), "system_fault" (for a motion: start it, then raise an
alarm half-way), "disconnect" (for a motion: start it, then close every session half-way, as a
cable pulled mid-move), "unknown" (answer with the unknown-packet form), or an int ErrorID to
answer with.

    with RmiController(world, time_scale=0.01) as ctrl:
        robot = RmiRobot("127.0.0.1", ctrl.port)
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from drivers import rmi_errors as rmi
from drivers.safety import JointLimits
from fakes._lineserver import LineServer
from fakes.clock import RealClock, SimClock, VirtualClock
from fakes.world import World

JOINTS = ("J1", "J2", "J3", "J4", "J5", "J6")
# The manual: "Initialize Failed ... RMI_MOVE program is selected ... choose another program";
# the number reported for it by users of the controller (MEMO-015). Not verified on hardware.
ERR_RMI_MOVE_SELECTED = 7015
TERM_TYPES = ("FINE", "CNT", "CR")
PoseOf = Callable[[np.ndarray], dict[str, float]]


@dataclass(frozen=True, eq=False)
class _Moving:
    """A motion whose duration is passing on a VirtualClock."""

    start: np.ndarray
    target: np.ndarray
    duration_s: float
    t0: float
    stop: threading.Event


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
        pose_of: PoseOf | None = None,
        accel_s: float = 0.0,
        settle_s: float = 0.0,
        **kw: Any,  # host, port: see LineServer
    ) -> None:
        super().__init__(**kw)
        self.world = world
        self.time_scale = float(time_scale)
        # the motion's profile (drivers.safety.JointLimits.move_time_s): each joint's time to
        # its speed, and the settling at a FINE stop; 0: at speed at once, no settling
        self.accel_s, self.settle_s = float(accel_s), float(settle_s)
        self.clock: SimClock = clock if clock is not None else RealClock()
        self.limits = limits or JointLimits.m710ic50()
        self.pose_of = pose_of
        self.session_port = 0
        self.alarm = False
        self.alarms: list[str] = []  # the active alarms' texts, newest first (FRC_ReadError)
        self.override_pct = 100
        self.uframe, self.utool = 0, 1
        # the newest requests, for tests (bounded: a soak of the simulated line runs for days)
        self.received: deque[dict[str, Any]] = deque(maxlen=1000)
        self.motion_durations_s: list[float] = []
        self._initialized = False
        self._next_seq = 1
        self._motion: asyncio.Task[None] | None = None
        self._moving: _Moving | None = None
        # virtual time passes here, off the event loop (an abort must be served meanwhile)
        self._mover: ThreadPoolExecutor | None = None
        if isinstance(self.clock, VirtualClock):
            self._mover = ThreadPoolExecutor(1, thread_name_prefix="rmi-motion")

    async def _start(self) -> None:
        await super()._start()
        self.session_port = await self._listen(0)

    def close(self) -> None:
        super().close()
        if self._mover is not None:
            self._mover.shutdown(wait=True, cancel_futures=True)

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
        except (json.JSONDecodeError, UnicodeDecodeError):
            msg = None
        if not isinstance(msg, dict):
            await self._send(writer, {"Command": "Unknown", "ErrorID": rmi.INVALID_COMMAND})
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
        if mode == "unknown" or not self._known(kind, name):
            await self._send(writer, self._unknown(kind, msg))
            return True
        if kind == "Instruction":
            half_way = mode if mode in ("system_fault", "disconnect") else None
            self._instruction(msg, writer, half_way=half_way)
            return True
        reply = self._reply(name, msg)
        await self._send(writer, {kind: name, **reply})
        return name != "FRC_Disconnect"

    def _known(self, kind: str, name: str) -> bool:
        known = {
            "Communication": ("FRC_Connect", "FRC_Disconnect"),
            "Command": tuple(self._COMMANDS),
            "Instruction": tuple(self._INSTRUCTIONS),
        }
        return name in known.get(kind, ())

    @staticmethod
    def _unknown(kind: str, msg: dict[str, Any]) -> dict[str, Any]:
        """The manual's reply to a packet it does not know (section 2.4.19)."""
        if kind == "Instruction":
            return {
                "Command": "Unknown",
                "ErrorID": rmi.INVALID_INSTRUCTION,
                **RmiController._seq_of(msg),
            }
        return {"Command": "Unknown", "ErrorID": rmi.INVALID_COMMAND}

    @staticmethod
    def _seq_of(msg: dict[str, Any]) -> dict[str, Any]:
        return {"SequenceID": msg["SequenceID"]} if "SequenceID" in msg else {}

    # -- commands -----------------------------------------------------------------------------
    _COMMANDS: ClassVar[dict[str, str]] = {
        "FRC_Initialize": "_initialize",
        "FRC_Abort": "_abort",
        "FRC_Reset": "_reset",
        "FRC_GetStatus": "_get_status",
        "FRC_ReadError": "_read_error",
        "FRC_ReadJointAngles": "_read_joint_angles",
        "FRC_ReadCartesianPosition": "_read_cartesian",
        "FRC_SetUFrameUTool": "_set_uframe_utool",
        "FRC_GetUFrameUTool": "_get_uframe_utool",
        "FRC_SetOverRide": "_set_override",
    }

    def _reply(self, name: str, msg: dict[str, Any]) -> dict[str, Any]:
        if name == "FRC_Connect":
            return {
                "ErrorID": 0,
                "PortNumber": self.session_port,
                "MajorVersion": 1,
                "MinorVersion": 0,
            }
        if name == "FRC_Disconnect":
            return {"ErrorID": 0}
        group = msg.get("Group", 1)
        if group != 1:
            return {"ErrorID": rmi.INVALID_GROUP}
        handler: Callable[[dict[str, Any]], dict[str, Any]] = getattr(self, self._COMMANDS[name])
        return handler(msg)

    def _initialize(self, msg: dict[str, Any]) -> dict[str, Any]:
        if msg.get("GroupMask", 1) != 1:
            return {"ErrorID": rmi.INVALID_GROUP_MASK}
        if self.alarm:
            return {"ErrorID": rmi.SERVO_OFF}
        if self._initialized:
            return {"ErrorID": ERR_RMI_MOVE_SELECTED}
        self._initialized, self._next_seq = True, 1
        return {"ErrorID": 0, "GroupMask": 1}

    def _abort(self, msg: dict[str, Any]) -> dict[str, Any]:
        if not self._initialized:
            return {"ErrorID": rmi.COMMAND_FAIL}
        self._stop_motion()
        self._initialized = False
        return {"ErrorID": 0}

    def _reset(self, msg: dict[str, Any]) -> dict[str, Any]:
        self.alarm = False
        self.alarms.clear()
        return {"ErrorID": 0}

    def _get_status(self, msg: dict[str, Any]) -> dict[str, Any]:
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

    def _read_error(self, msg: dict[str, Any]) -> dict[str, Any]:
        """The active alarms, newest first: ``Count`` (1..5, default 1) of them in ErrorData,
        ErrorData2 .. ErrorData<Count>, each "No Error" when there is none (B-84184EN 2.3.5 as
        FANUC's fanuc_driver packets.hpp has it; "No Error" as a controller answers)."""
        count = msg.get("Count", 1)
        if not (type(count) is int and 1 <= count <= rmi.READ_ERROR_MAX_COUNT):
            return {"ErrorID": rmi.INVALID_VALUE}
        texts = [*self.alarms[:count], *[rmi.NO_ERROR_TEXT] * count][:count]
        keys = ["ErrorData", *(f"ErrorData{k}" for k in range(2, count + 1))]
        return {"ErrorID": 0, "Count": count, **dict(zip(keys, texts, strict=True))}

    def _read_joint_angles(self, msg: dict[str, Any]) -> dict[str, Any]:
        q = self.world.joints_deg()
        angles = {j: float(v) for j, v in zip(JOINTS, q, strict=True)}
        return {
            "ErrorID": 0,
            "TimeTag": 0,
            "JointAngle": angles | {"J7": 0.0, "J8": 0.0, "J9": 0.0},
            "Group": 1,
        }

    def _read_cartesian(self, msg: dict[str, Any]) -> dict[str, Any]:
        if self.pose_of is None:
            return {"ErrorID": rmi.INTERNAL_ERROR}
        pose = self.pose_of(self.world.joints_deg())
        config = {"UToolNumber": self.utool, "UFrameNumber": self.uframe, "Front": 1, "Up": 1}
        config |= {"Left": 0, "Flip": 0, "Turn4": 0, "Turn5": 0, "Turn6": 0}
        position = {k: float(pose[k]) for k in ("X", "Y", "Z", "W", "P", "R")}
        position |= {"Ext1": 0.0, "Ext2": 0.0, "Ext3": 0.0}
        return {
            "ErrorID": 0,
            "TimeTag": 0,
            "Configuration": config,
            "Position": position,
            "Group": 1,
        }

    def _set_uframe_utool(self, msg: dict[str, Any]) -> dict[str, Any]:
        uframe, utool = msg.get("UFrameNumber"), msg.get("UToolNumber")
        if not (isinstance(uframe, int) and 0 <= uframe <= 9):
            return {"ErrorID": rmi.INVALID_UFRAME}
        if not (isinstance(utool, int) and 1 <= utool <= 10):
            return {"ErrorID": rmi.INVALID_UTOOL}
        self.uframe, self.utool = uframe, utool
        return {"ErrorID": 0, "Group": 1}

    def _get_uframe_utool(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"ErrorID": 0, "UFrameNumber": self.uframe, "UToolNumber": self.utool, "Group": 1}

    def _set_override(self, msg: dict[str, Any]) -> dict[str, Any]:
        value = msg.get("Value")
        if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 100):
            return {"ErrorID": rmi.INVALID_OVERRIDE}
        self.override_pct = value
        return {"ErrorID": 0}

    # -- instructions -------------------------------------------------------------------------
    _INSTRUCTIONS: ClassVar[tuple[str, ...]] = (
        "FRC_JointMotionJRep",
        "FRC_JointRelativeJRep",
        "FRC_WaitTime",
        "FRC_SetUFrame",
        "FRC_SetUTool",
    )

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
        previous = self._motion
        self._motion = self._spawn(self._run_instruction(previous, msg, writer, half_way))

    def _check_instruction(self, msg: dict[str, Any]) -> int:
        if self.alarm:
            return rmi.SERVO_OFF
        if not self._initialized:
            return rmi.NOT_RUNNING
        if msg.get("SequenceID") != self._next_seq:
            return rmi.INVALID_SEQUENCE
        name = msg["Instruction"]
        if name == "FRC_WaitTime":
            t = msg.get("Time")
            ok = isinstance(t, int | float) and not isinstance(t, bool) and t >= 0
            return 0 if ok else rmi.INVALID_VALUE
        if name == "FRC_SetUFrame":
            n = msg.get("FrameNumber")
            return 0 if isinstance(n, int) and 0 <= n <= 9 else rmi.INVALID_UFRAME
        if name == "FRC_SetUTool":
            n = msg.get("ToolNumber")
            return 0 if isinstance(n, int) and 1 <= n <= 10 else rmi.INVALID_UTOOL
        return self._check_motion(msg)

    def _check_motion(self, msg: dict[str, Any]) -> int:
        try:
            q = np.array([float(msg["JointAngle"][j]) for j in JOINTS])
        except (KeyError, TypeError, ValueError):
            return rmi.rmit(23)  # Invalid Position Data
        if msg.get("SpeedType") != "Percent":
            return rmi.INVALID_SPEED_TYPE
        speed = msg.get("Speed")
        if not (
            isinstance(speed, int | float) and not isinstance(speed, bool) and 1 <= speed <= 100
        ):
            return rmi.INVALID_SPEED
        if msg.get("TermType") not in TERM_TYPES:
            return rmi.INVALID_TERM_TYPE
        if msg["Instruction"] == "FRC_JointRelativeJRep":
            return 0  # the destination is known when the motion starts
        return 0 if bool(self.limits.contains(q[None])[0]) else rmi.INVALID_DESTINATION

    async def _run_instruction(
        self,
        previous: asyncio.Task[None] | None,
        msg: dict[str, Any],
        writer: asyncio.StreamWriter,
        half_way: str | None,
    ) -> None:
        if previous is not None:
            with contextlib.suppress(asyncio.CancelledError):
                await previous
        name, seq = msg["Instruction"], msg["SequenceID"]
        error = 0
        if name == "FRC_WaitTime" and self._mover is not None:
            await self._elapse(float(msg["Time"]) * self.time_scale, threading.Event())
        elif name == "FRC_WaitTime":
            await asyncio.sleep(float(msg["Time"]) * self.time_scale / self.clock.scale)
        elif name == "FRC_SetUFrame":
            self.uframe = int(msg["FrameNumber"])
        elif name == "FRC_SetUTool":
            self.utool = int(msg["ToolNumber"])
        else:
            error = await self._run_motion(msg, half_way)
            if error < 0:
                return  # a fault half-way: no reply (FRC_SystemFault sent, or sessions gone)
        await self._send(writer, {"Instruction": name, "ErrorID": error, "SequenceID": seq})

    async def _run_motion(self, msg: dict[str, Any], half_way: str | None) -> int:
        start = self.world.joints_deg()
        q = np.array([float(msg["JointAngle"][j]) for j in JOINTS])
        target = start + q if msg["Instruction"] == "FRC_JointRelativeJRep" else q
        if not bool(self.limits.contains(target[None])[0]):
            return rmi.INVALID_DESTINATION
        speed = float(msg["Speed"]) * self.override_pct / 1e4
        settle_s = self.settle_s if msg.get("TermType") == "FINE" else 0.0
        move_s = self.limits.move_time_s(start, target, speed, self.accel_s, settle_s)
        duration = move_s * self.time_scale
        self.motion_durations_s.append(duration)
        if self._mover is not None:
            return await self._run_motion_virtual(start, target, duration, half_way)
        t0 = self.clock.monotonic()
        # the joints follow the clock (not a count of sleeps, whose overheads would add up)
        while (frac := (self.clock.monotonic() - t0) / duration if duration > 0 else 1.0) < 1.0:
            self.world.set_joints_deg(start + (target - start) * frac)
            if half_way is not None and frac >= 0.5:
                await self._half_way_fault(half_way)
                return -1
            left_real_s = (1.0 - frac) * duration / self.clock.scale
            await asyncio.sleep(min(0.01, left_real_s))
        if half_way is not None:  # a move too short to be seen half-way still fails
            await self._half_way_fault(half_way)
            return -1
        self.world.set_joints_deg(target)
        return 0

    async def _elapse(self, seconds: float, stop: threading.Event) -> None:
        """Let `seconds` pass on the VirtualClock (in the mover thread)."""
        assert self._mover is not None and isinstance(self.clock, VirtualClock)
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(self._mover, self.clock.elapse, seconds, stop)

    async def _run_motion_virtual(
        self, start: np.ndarray, target: np.ndarray, duration: float, half_way: str | None
    ) -> int:
        """The motion's duration (half of it, for a fault half-way) passes on the clock; the
        joints land at its end, or where it is when an abort stops it (`_halt`)."""
        moving = _Moving(start, target, duration, self.clock.monotonic(), threading.Event())
        self._moving = moving
        try:
            await self._elapse(duration * (0.5 if half_way is not None else 1.0), moving.stop)
        except asyncio.CancelledError:
            self._halt()
            raise
        if moving.stop.is_set():  # halted (the task is being cancelled): no reply
            return -1
        self._moving = None
        if half_way is not None:
            self.world.set_joints_deg(start + (target - start) * 0.5)
            await self._half_way_fault(half_way)
            return -1
        self.world.set_joints_deg(target)
        return 0

    def _halt(self) -> None:
        """Stop a motion passing on the VirtualClock where it is now."""
        moving, self._moving = self._moving, None
        if moving is None:
            return
        moving.stop.set()
        done = self.clock.monotonic() - moving.t0
        frac = min(done / moving.duration_s, 1.0) if moving.duration_s > 0 else 1.0
        self.world.set_joints_deg(moving.start + (moving.target - moving.start) * frac)

    async def _half_way_fault(self, mode: str) -> None:
        if mode == "system_fault":
            await self._system_fault()
            return
        for writer in list(self._writers):  # "disconnect": the sessions vanish, no goodbye
            writer.close()

    async def _system_fault(self) -> None:
        self.alarm, self._initialized = True, False
        self.alarms.insert(0, "SRVO-050 Collision Detect Alarm (G:1 A:2)")
        del self.alarms[rmi.READ_ERROR_MAX_COUNT :]  # what FRC_ReadError can show; bounded
        current = asyncio.current_task()
        if self._motion is not None and self._motion is not current:
            self._halt()
            self._motion.cancel()
        await self._broadcast(
            {"Communication": "FRC_SystemFault", "SequenceID": self._next_seq - 1}
        )

    def _stop_motion(self) -> None:
        if self._motion is not None:
            self._halt()
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
