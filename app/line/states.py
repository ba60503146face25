"""The in-line service's vocabulary, shared by the service and its collaborators (the
operator's commands, the step handling, the status reply): its states, the alarms that hold
the cell in FAULT, and the UTC text of the service's clock."""

from __future__ import annotations

from datetime import UTC, datetime
from enum import StrEnum


class State(StrEnum):
    """The service's state (DESIGN.md section 6)."""

    STARTING = "starting"
    IDLE = "idle"
    MEASURING = "measuring"
    PAUSED = "paused"
    FAULT = "fault"
    STOPPED = "stopped"


#: alarms that hold the cell in FAULT until a reset
FAULT_CODES = ("device_fault", "robot_not_home", "internal_error", "state_storage")


def utc_text(t: float) -> str:
    """ISO 8601 UTC of a clock time (seconds since the epoch)."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="seconds")
