"""A pymodbus server emulating the TP program RVIS_MBX (docs/fanuc-modbus-mailbox.md): the FANUC
register mailbox served by a controller without RMI, moving a World's robot.

Each Modbus access is one scan of the TP logic (see fakes/_modbus_server.py): a new CMD counter
starts a motion (refused with an error code outside the joint limits), which completes after
max |dq| / speed x time_scale seconds; RESET clears a fault; ABORT stops the motion.
``fault_next_motion(code)`` makes the next motion stop half-way with that alarm code.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers._modbus import floats_to_words, words_to_floats
from drivers.modbus_robot import MAILBOX, STATUS_FAULT, STATUS_IDLE, STATUS_MOVING
from drivers.safety import JointLimits
from fakes._modbus_server import RegisterServer
from fakes.world import World

ERR_LIMIT = 17  # illustrative TP error codes (the fake's own)
ERR_SPEED = 18
ERR_ABORTED = 99


class ModbusRobotServer(RegisterServer):
    """``with ModbusRobotServer(world, time_scale=0.01) as s: ModbusRobot("127.0.0.1", s.port)``"""

    def __init__(
        self,
        world: World,
        *,
        time_scale: float = 1.0,
        limits: JointLimits | None = None,
        base: int = 0,
        **kw: Any,
    ) -> None:
        super().__init__(size=base + MAILBOX.SIZE, **kw)
        self.world, self.time_scale, self.base = world, float(time_scale), base
        self.limits = limits or JointLimits.m710ic50()
        self._seen = {"CMD": 0, "RESET": 0, "ABORT": 0}
        self._motion: tuple[np.ndarray, np.ndarray, float, float, int] | None = None
        self._fault_next: int | None = None
        self.status, self.error = STATUS_IDLE, 0

    def fault_next_motion(self, code: int) -> None:
        self._fault_next = code

    # -- one TP scan --------------------------------------------------------------------------
    def scan(self, now: float, regs: list[int], written: dict[int, int]) -> None:
        def get(offset: int, n: int = 1) -> list[float]:
            a = self.base + offset
            words = [written.get(a + i, regs[a + i]) for i in range(2 * n)]
            return words_to_floats(words)

        self._advance(now, regs)
        for name in ("RESET", "ABORT", "CMD"):
            value = int(get(getattr(MAILBOX, name))[0])
            if value != self._seen[name]:
                self._seen[name] = value
                getattr(self, f"_on_{name.lower()}")(now, regs, value, get)
        self._put(regs, MAILBOX.STATUS, [self.status, self.error])
        self._put(regs, MAILBOX.CURRENT, list(self.world.joints_deg()))
        self._put(regs, MAILBOX.BEAT, [int((now - self.t0) * 10) % 10_000])

    def _advance(self, now: float, regs: list[int]) -> None:
        if self._motion is None:
            return
        start, target, t0, duration, cmd = self._motion
        frac = 1.0 if duration <= 0 else min((now - t0) / duration, 1.0)
        if self._fault_next is not None and frac >= 0.5:
            self.world.set_joints_deg(start + 0.5 * (target - start))
            self._motion, self.status, self.error = None, STATUS_FAULT, self._fault_next
            self._fault_next = None
            return
        self.world.set_joints_deg(start + frac * (target - start))
        if frac >= 1.0:
            self._motion, self.status = None, STATUS_IDLE
            self._put(regs, MAILBOX.DONE, [cmd])

    def _on_reset(self, now: float, regs: list[int], value: int, get: Any) -> None:
        if self.status == STATUS_FAULT:
            self.status, self.error = STATUS_IDLE, 0

    def _on_abort(self, now: float, regs: list[int], value: int, get: Any) -> None:
        if self._motion is not None:
            self._motion, self.status, self.error = None, STATUS_FAULT, ERR_ABORTED

    def _on_cmd(self, now: float, regs: list[int], value: int, get: Any) -> None:
        self._put(regs, MAILBOX.ACK, [value])
        if self.status == STATUS_FAULT or self._motion is not None:
            return  # the TP program is not waiting for a command
        speed, *q = get(MAILBOX.SPEED, 7)
        target = np.array(q)
        if not 0 < speed <= 100:
            self.status, self.error = STATUS_FAULT, ERR_SPEED
            return
        if not self.limits.contains(target[None])[0]:
            self.status, self.error = STATUS_FAULT, ERR_LIMIT
            return
        start = self.world.joints_deg()
        duration = self.limits.move_time_s(start, target, speed / 100.0) * self.time_scale
        self._motion = (start, target, now, duration, value)
        self.status = STATUS_MOVING

    def _put(self, regs: list[int], offset: int, values: list[float]) -> None:
        a = self.base + offset
        words = floats_to_words(values)
        regs[a : a + len(words)] = words
