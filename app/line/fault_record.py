"""The service's faults as one record (`FaultRecord`, the service's `fault`): what the status
reply shows and the operator's reset looks at. Written by app.line.faults (an alarm kept in
memory while the state storage fails, a device's last error, the device of the fault in force)
and app.line.startup (a device unreachable at start: its retries)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class FaultRecord:
    """storage_failed: the state storage failed, until a reset finds it writing again, and the
    alarms raised meanwhile (`unstored_alarms`, negative ids); device_errors: each device's
    last error, family -> {"error", "utc"}; family: the device of the fault in force (None:
    not known, "": none of them); retry: while a device unreachable at start is retried,
    {"attempts", "next_utc", "wait_s"}."""

    storage_failed: bool = False
    unstored_alarms: list[dict[str, Any]] = field(default_factory=list)
    device_errors: dict[str, dict[str, str]] = field(default_factory=dict)
    family: str | None = None
    retry: dict[str, Any] | None = None

    def stored_again(self) -> None:
        """The storage writes again and the alarms kept meanwhile are stored."""
        self.unstored_alarms.clear()
        self.storage_failed = False
