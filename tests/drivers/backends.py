"""The back ends each family's contract suite runs on, and the safety profile for real devices.

python-can's back-to-back idea: one test body per behaviour, run on every fake back end (always,
in the test command) and on a real device when ``RVIS_<FAMILY>_URL`` names one (e.g.
``RVIS_ROBOT_URL=rmi://10.0.0.5:16001``). The real device's run is marked ``hardware`` (``-m
hardware`` selects the real devices' runs alone) and exists only when its URL is set. A test
that needs something only a fake can do (inject a controller alarm, freeze the PLC heartbeat)
asks the fake's peer for it (``fake_only``) and is skipped on hardware.

The safety profile applies to every back end, so that no test asks a real device for more than
the fakes do (docs/commissioning.md, "Running the contract suites on the cell"):

- robot: it must stand at home when each test starts (``RVIS_ROBOT_HOME_DEG``, default the
  cell's ``[line] home_deg``; the test fails naming the joints otherwise), and it moves only
  inside the joint box home +- ``RVIS_ROBOT_BOX_DEG`` (default 5, at most 10 deg), at
  ``speed_pct`` 10 and, where the controller has one, a speed override of 10 %. The box and the
  speed are the driver's own SafetyGuard (keep-in box, ``max_speed_pct``): a target outside is
  refused before it leaves the process, whatever a test asks. Every test ends at home;
- PLC: opened read-only (nothing written) unless ``RVIS_PLC_WRITE=1``; the handshake tests
  wait up to ``RVIS_PLC_WINDOW_S`` (default 120 s) for a clamp window;
- galvo: commands only within ``RVIS_GALVO_VOLTS`` (default ``-7.5,7.5``);
- camera: the hardware trigger line must be idle (the trigger test expects no frame).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from drivers.errors import DeviceConfigError
from drivers.robot import Robot
from drivers.safety import Envelope, JointBox, JointLimits, SafetyGuard

F64 = NDArray[np.float64]
HARDWARE = "hardware"
MAX_BOX_DEG = 10.0
PROFILE_SPEED_PCT = 10.0
PROFILE_OVERRIDE_PCT = 10


def hardware_url(family: str) -> str | None:
    """The real device's URL for `family` (``RVIS_<FAMILY>_URL``), or None."""
    return os.environ.get(f"RVIS_{family.upper()}_URL") or None


def real_url(family: str) -> str:
    """The real device's URL for a fixture opening it (its param exists only when set)."""
    url = hardware_url(family)
    assert url is not None, f"RVIS_{family.upper()}_URL not set"
    return url


def backends(family: str, fakes: Sequence[Any]) -> list[Any]:
    """Fixture params: the fake back ends, and the real device (marked ``hardware``) when
    ``RVIS_<FAMILY>_URL`` is set; like python-can's back-to-back suites, a real device's run
    exists only when it is configured, so the test command lists no skips for it."""
    if hardware_url(family) is None:
        return list(fakes)
    return [*fakes, pytest.param(HARDWARE, marks=pytest.mark.hardware)]


def _env_numbers(name: str, default: Sequence[float], n: int) -> tuple[float, ...]:
    text = os.environ.get(name)
    if not text:
        return tuple(float(v) for v in default)
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        pytest.fail(f"{name}={text!r}: expected {n} comma-separated numbers", pytrace=False)
    if len(values) != n or not all(np.isfinite(values)):
        pytest.fail(f"{name}={text!r}: expected {n} finite numbers", pytrace=False)
    return values


@dataclass(frozen=True)
class RobotProfile:
    """Home, the keep-in joint box around it, the speed and the override of every motion."""

    home_deg: tuple[float, ...]
    box_deg: float
    speed_pct: float = PROFILE_SPEED_PCT
    override_pct: int = PROFILE_OVERRIDE_PCT
    home_tol_deg: float = 0.05

    def guard(self) -> SafetyGuard:
        home = np.asarray(self.home_deg)
        box = JointBox(tuple(home - self.box_deg), tuple(home + self.box_deg))
        return SafetyGuard(
            limits=JointLimits.m710ic50(),
            envelope=Envelope(keep_in=box),
            max_speed_pct=self.speed_pct,
        )

    def inside(self, fractions: Sequence[float]) -> F64:
        """home + fractions x box (each fraction in [-1, 1]): a target inside the box."""
        f = np.asarray(fractions, dtype=np.float64)
        assert f.shape == (6,) and np.all(np.abs(f) <= 1.0)
        return np.asarray(self.home_deg) + f * self.box_deg

    def at_home(self, robot: Robot) -> bool:
        q = robot.joints_deg()
        return bool(np.all(np.abs(q - np.asarray(self.home_deg)) <= self.home_tol_deg))

    def start(self, robot: Robot) -> None:
        """Check the robot stands at home and set the override (controllers that have one)."""
        if not self.at_home(robot):
            q = ", ".join(f"{v:.3f}" for v in robot.joints_deg())
            pytest.fail(f"{robot.name}: not at home ({q} deg): move it home first", pytrace=False)
        try:
            robot.set_override_pct(self.override_pct)
        except DeviceConfigError as exc:  # the Modbus mailbox: speed_pct alone limits it
            if "no speed override" not in str(exc):
                raise

    def finish(self, robot: Robot) -> None:
        """Back home after a test (not when closed or with a fault latched: a person looks)."""
        if robot.is_open and robot.fault is None and not self.at_home(robot):
            robot.move_joints(self.home_deg, speed_pct=self.speed_pct)


@cache
def robot_profile() -> RobotProfile:
    """The robot's safety profile from the environment (validated once)."""
    from app.config.line import LineSettings

    home = _env_numbers("RVIS_ROBOT_HOME_DEG", LineSettings().home_deg, 6)
    (box,) = _env_numbers("RVIS_ROBOT_BOX_DEG", (5.0,), 1)
    if not 0 < box <= MAX_BOX_DEG:
        pytest.fail(f"RVIS_ROBOT_BOX_DEG={box:g}: must be in (0, {MAX_BOX_DEG:g}]", pytrace=False)
    return RobotProfile(home_deg=home, box_deg=box)


def galvo_volts() -> tuple[float, float]:
    """The command range [V] the galvo suite may use (``RVIS_GALVO_VOLTS``)."""
    lo, hi = _env_numbers("RVIS_GALVO_VOLTS", (-7.5, 7.5), 2)
    if not lo < hi:
        pytest.fail(f"RVIS_GALVO_VOLTS: expected lo < hi, got {lo:g}, {hi:g}", pytrace=False)
    return lo, hi


def plc_writes_allowed() -> bool:
    """``RVIS_PLC_WRITE=1``: the PLC suite may write the app's outputs on the real PLC."""
    return os.environ.get("RVIS_PLC_WRITE") == "1"


def plc_window_s() -> float:
    (seconds,) = _env_numbers("RVIS_PLC_WINDOW_S", (120.0,), 1)
    return seconds


def fake_only(peer: Any, what: str) -> Any:
    """The fake's peer for a test that needs it; skips the test on a real device."""
    if peer is None:
        pytest.skip(f"needs the fake's {what}; a real device cannot be made to do it")
    return peer
