"""The limits of the quality gates of an identification (calib/gates.py checks a result against
them): plain numbers, no numerics imported, so that the cell file's `[calibration]` and
`[service]` defaults read them without loading numpy (a command that only reads its settings,
`rvis status`, starts fast)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Gates:
    """Limits of an acceptable identification (None: that change is not checked)."""

    max_rms_mm: float = 0.25
    max_condition: float = 1000.0
    max_joint_change_mm: float = 5.0
    max_joint_change_rad: float = math.radians(1.0)
    max_sensor_change_mm: float = 20.0
    max_sensor_change_rad: float = math.radians(5.0)
    max_base_change_mm: float | None = None
    max_base_change_rad: float | None = None
    #: in-line only: the candidate's RMS on held-out measurements must not exceed this times
    #: that of the parameters in force (None: not compared)
    max_holdout_ratio: float | None = None


#: An offline identification against the nominal model: the part->base pose is unbounded
#: (its guess may be far off; the identification starts from a closed-form alignment).
OFFLINE = Gates()
#: An in-line identification against the parameters in force: every change bounded, tighter
#: for the hand-eye, and the candidate must predict held-out measurements at least as well.
INLINE = Gates(
    max_sensor_change_mm=5.0,
    max_sensor_change_rad=math.radians(2.0),
    max_base_change_mm=5.0,
    max_base_change_rad=math.radians(1.0),
    max_holdout_ratio=1.0,
)
