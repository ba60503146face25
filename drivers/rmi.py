"""FANUC Remote Motion Interface (RMI, option R912 on R-30iB Plus): ``rmi://host:16001``.

JSON objects terminated by CRLF over TCP. ``FRC_Connect`` on port 16001 names the session port
(``PortNumber``); all further packets go there. Commands (FRC_Initialize, FRC_Abort, FRC_Reset,
FRC_GetStatus, FRC_ReadError, FRC_ReadJointAngles, FRC_SetOverRide with ``Value`` 1..100) are
answered at once; instructions (FRC_JointMotionJRep) carry consecutive ``SequenceID`` values from
1 and are answered when executed.

Every reply the manual (B-84184EN) defines maps to a typed error at once:

- ``ErrorID`` != 0 in the reply -> DeviceFault(code=ErrorID) (``RMIT-N`` = 2556928 + N, named
  from drivers/rmi_errors.py); a motion's fault is latched by the Robot base class;
- the unknown-packet reply ``{"Command": "Unknown", "ErrorID": N}`` (the controller did not
  understand what we sent) -> DeviceFault(code=N), not a wait for a reply that never comes;
- unsolicited ``FRC_SystemFault`` (an alarm stopped the robot) -> DeviceFault, latched, with the
  controller's alarm text (FRC_ReadError) when it can be read;
- unsolicited ``FRC_Terminate`` (the controller closed the session) -> DeviceConnectionError;
- socket errors -> DeviceConnectionError / DeviceTimeout; bad JSON or a reply without ErrorID ->
  ProtocolError.

One motion at a time: the driver waits for each instruction's reply before it sends the next;
``abort()`` may come from another thread during that wait (see drivers/robot.py).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from drivers._linesock import LineJsonSocket
from drivers.errors import (
    DeviceConnectionError,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
)
from drivers.rmi_errors import NO_ERROR_TEXT, RMIT_BASE, describe_error
from drivers.robot import FloatArray, Robot, RobotStatus
from drivers.safety import SafetyGuard
from drivers.url import DeviceUrl

DEFAULT_PORT = 16001
JOINTS = ("J1", "J2", "J3", "J4", "J5", "J6")
__all__ = ["DEFAULT_PORT", "RMIT_BASE", "RmiRobot"]


class RmiRobot(Robot):
    """``RmiRobot("10.0.0.5", 16001, guard=SafetyGuard(...))``; open() connects."""

    def __init__(
        self,
        host: str,
        port: int = DEFAULT_PORT,
        *,
        guard: SafetyGuard | None = None,
        timeout_s: float = 5.0,
        motion_timeout_s: float = 120.0,
        name: str = "",
    ) -> None:
        super().__init__(
            guard=guard,
            timeout_s=timeout_s,
            motion_timeout_s=motion_timeout_s,
            name=name or f"rmi://{host}:{port}",
        )
        self.host, self.port = host, int(port)
        self._sock: LineJsonSocket | None = None
        self._seq = 1
        self._initialized = False
        self.version = ""
        # abort() runs in another thread while _move waits for its reply: the motion thread is
        # the only reader of the socket then; _io guards the sends and the in-motion state
        self._io = threading.Lock()
        self._in_motion = False
        self._abort_sent = False
        self._abort_acked = threading.Event()
        self._abort_failure: DeviceError | None = None

    @classmethod
    def from_url(cls, url: DeviceUrl, **options: Any) -> RmiRobot:
        host, port = url.address(DEFAULT_PORT)
        return cls(host, port, **options)

    # -- life cycle ---------------------------------------------------------------------------
    def _open(self) -> None:
        hello = LineJsonSocket(
            self.host, self.port, timeout_s=self.timeout_s, terminator=b"\r\n", trace=self.trace
        )
        hello.connect()
        try:
            hello.send({"Communication": "FRC_Connect"})
            reply = self._expect(hello, "Communication", "FRC_Connect", self.timeout_s)
        finally:
            hello.close()
        session_port = reply.get("PortNumber")
        if not isinstance(session_port, int) or not 0 < session_port < 65536:
            raise ProtocolError(f"{self.name}: FRC_Connect reply without a valid PortNumber")
        self.version = f"{reply.get('MajorVersion', '?')}.{reply.get('MinorVersion', '?')}"
        sock = LineJsonSocket(
            self.host, session_port, timeout_s=self.timeout_s, terminator=b"\r\n", trace=self.trace
        )
        sock.connect()
        self._sock, self._initialized = sock, False

    def _close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is None:
            return
        try:
            sock.send({"Communication": "FRC_Disconnect"})
            self._expect(sock, "Communication", "FRC_Disconnect", min(self.timeout_s, 1.0))
        except DeviceError as exc:
            self.log.debug("%s: disconnect: %s", self.name, exc)
        finally:
            sock.close()

    def describe(self) -> str:
        self._check_open()
        return f"FANUC RMI {self.version} at {self.host}:{self.port}"

    # -- primitives ---------------------------------------------------------------------------
    def _read_joints(self) -> FloatArray:
        reply = self._command("FRC_ReadJointAngles", Group=1)
        angles = reply.get("JointAngle")
        try:
            return np.array([float(angles[j]) for j in JOINTS])  # type: ignore[index]
        except (TypeError, KeyError, ValueError) as exc:
            raise ProtocolError(f"{self.name}: bad JointAngle in {reply}") from exc

    def _status(self) -> RobotStatus:
        r = self._command("FRC_GetStatus")
        try:
            servo, motion = int(r["ServoReady"]), int(r["RMIMotionStatus"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ProtocolError(f"{self.name}: bad FRC_GetStatus reply {r}") from exc
        override = r.get("Override")
        return RobotStatus(
            servo_ready=servo == 1,
            moving=motion != 0,
            fault=servo != 1,
            override_pct=override if isinstance(override, int) else None,
        )

    def _set_override(self, override_pct: int) -> None:
        self._command("FRC_SetOverRide", Value=override_pct)

    def _move(self, q_deg: FloatArray, speed_pct: float, timeout_s: float) -> None:
        if not self._initialized:
            self._initialize()
        seq = self._seq
        packet = {
            "Instruction": "FRC_JointMotionJRep",
            "SequenceID": seq,
            "JointAngle": {j: round(float(v), 4) for j, v in zip(JOINTS, q_deg, strict=True)}
            | {"J7": 0.0, "J8": 0.0, "J9": 0.0},
            "SpeedType": "Percent",
            "Speed": max(1, round(speed_pct)),
            "TermType": "FINE",
            "TermValue": 0,
        }
        self._seq += 1
        sock = self._session()
        with self._io:
            sock.send(packet)
            self._in_motion = True
        try:
            self._expect(sock, "Instruction", "FRC_JointMotionJRep", timeout_s, seq=seq)
        except DeviceTimeout:
            with self._io:
                self._in_motion = False
            if not self._abort_sent:
                self._best_effort_abort()
            raise
        finally:
            with self._io:
                self._in_motion = False
            self._await_abort_reply(sock)

    def _abort(self) -> None:
        with self._io:
            in_motion = self._in_motion
            if in_motion:  # the motion thread reads the reply; send now, wait for its ack
                self._abort_acked.clear()
                self._abort_sent, self._abort_failure = True, None
                self._session().send({"Command": "FRC_Abort"})
        if in_motion:
            if not self._abort_acked.wait(self.timeout_s):
                raise DeviceTimeout(f"{self.name}: FRC_Abort not answered in {self.timeout_s:g} s")
            self._initialized = False
            if self._abort_failure is not None:
                raise self._abort_failure
            return
        with self._lock:  # no motion: stop RMI_MOVE if it runs (aborting nothing is RMIT-014)
            if int(self._command("FRC_GetStatus").get("RMIMotionStatus", 0)) != 0:
                self._command("FRC_Abort")
            self._initialized = False

    def _await_abort_reply(self, sock: LineJsonSocket) -> None:
        """After a motion ended while an abort was in flight, read the FRC_Abort reply (the
        motion thread is the socket's only reader until then)."""
        if not self._abort_sent or self._abort_acked.is_set():
            return
        try:
            self._expect(sock, "Command", "FRC_Abort", self.timeout_s)
        except DeviceError as exc:
            self.log.warning("%s: no FRC_Abort reply: %s", self.name, exc)
            self._abort_failure = exc
        finally:
            self._abort_sent = False
            self._abort_acked.set()

    def _reset(self) -> None:
        self._command("FRC_Reset")
        self._initialize()

    # -- packets ------------------------------------------------------------------------------
    def _initialize(self) -> None:
        if int(self._command("FRC_GetStatus").get("RMIMotionStatus", 0)) != 0:
            self._command("FRC_Abort")
        self._command("FRC_Initialize", GroupMask=1)
        self._seq, self._initialized = 1, True

    def _best_effort_abort(self) -> None:
        try:
            self._abort()
        except DeviceError as exc:
            self.log.warning("%s: abort after timeout failed: %s", self.name, exc)

    def _session(self) -> LineJsonSocket:
        if self._sock is None:
            raise DeviceConnectionError(f"{self.name}: no session")
        return self._sock

    def _command(self, name: str, **fields: Any) -> dict[str, Any]:
        sock = self._session()
        sock.send({"Command": name, **fields})
        return self._expect(sock, "Command", name, self.timeout_s)

    def _expect(
        self, sock: LineJsonSocket, kind: str, name: str, timeout_s: float, seq: int | None = None
    ) -> dict[str, Any]:
        """Read until the reply to (kind, name[, seq]); handle unsolicited packets."""
        deadline = time.monotonic() + timeout_s
        while True:
            msg = sock.recv(max(deadline - time.monotonic(), 0.0))
            if "Unknown" in (msg.get("Command"), msg.get("Instruction"), msg.get("Communication")):
                code = msg.get("ErrorID")
                code = code if isinstance(code, int) else 0
                raise DeviceFault(
                    f"{self.name}: the controller did not understand {name}: "
                    f"{describe_error(code)}",
                    code=code,
                )
            unsolicited = msg.get("Communication")
            if unsolicited == "FRC_SystemFault":
                self._initialized = False
                fault = DeviceFault(
                    f"{self.name}: controller system fault (SequenceID {msg.get('SequenceID')})"
                    f"{self._alarm_text(sock)}",
                    code=-1,
                )
                self._latch_fault(fault)
                raise fault
            if unsolicited == "FRC_Terminate":
                sock.close()
                raise DeviceConnectionError(f"{self.name}: controller terminated the session")
            if self._abort_sent and msg.get("Command") == "FRC_Abort":
                self._abort_reply(msg)
                if name != "FRC_Abort":
                    raise DeviceFault(f"{self.name}: {name} aborted", code=0)
                return msg
            if msg.get(kind) != name or (seq is not None and msg.get("SequenceID") != seq):
                self.log.debug("%s: ignoring %s", self.name, msg)
                continue
            code = msg.get("ErrorID")
            if not isinstance(code, int):
                raise ProtocolError(f"{self.name}: {name} reply without ErrorID: {msg}")
            if code != 0:
                if kind == "Instruction":
                    self._initialized = False
                raise DeviceFault(f"{self.name}: {name} failed: {describe_error(code)}", code=code)
            return msg

    def _alarm_text(self, sock: LineJsonSocket) -> str:
        """``: <alarm>`` from FRC_ReadError after a system fault, or "" if it cannot be read."""
        try:
            sock.send({"Command": "FRC_ReadError"})
            reply = self._expect(sock, "Command", "FRC_ReadError", min(self.timeout_s, 1.0))
        except DeviceError as exc:
            self.log.debug("%s: FRC_ReadError: %s", self.name, exc)
            return ""
        text = reply.get("ErrorData")
        if not isinstance(text, str) or text.strip() in ("", NO_ERROR_TEXT):
            return ""
        return f": {text}"

    def _abort_reply(self, msg: dict[str, Any]) -> None:
        code = msg.get("ErrorID")
        if code != 0:
            code = code if isinstance(code, int) else -1
            self._abort_failure = DeviceFault(
                f"{self.name}: FRC_Abort failed: {describe_error(code)}", code=code
            )
        self._abort_sent = False
        self._abort_acked.set()
