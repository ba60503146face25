"""The queue between the service's event bus and the OPC UA server process (in the service's
process; app.line.opcua.server's feed thread takes from it).

Alarm events (ALARM_EVENTS: raised, acknowledged, shelved, unshelved, cleared) and body
results (`body`: one OPC UA BodyResultEventType event each, app.line.opcua.results) are kept
each in order: the server process applies every alarm change to its condition, so an alarm
raised and cleared between two status replies is still two OPC UA events, and fires one event
per body. Every other event only says "the status changed": one waiting behind another is
merged into it (the latest time, `stopped` kept), since the next status reply carries both. So
the queue holds at most `maxsize` entries (kept events, with merged ticks between them), and
only a server process that keeps up with none of them for that long loses kept events: the
oldest first, each counted (`lost`, in `rvis status` as `opcua.events_dropped`) and logged at
most once per LOG_EVERY_S.
`offer` never blocks the service.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from app.line.events import Subscription
from app.line.opcua import FEED_NAME

log = logging.getLogger("rvis.line.opcua")

ALARM_EVENTS = frozenset(
    {"alarm", "alarm_acked", "alarm_shelved", "alarm_unshelved", "alarm_cleared"}
)
#: the state an alarm event leaves its alarm in, for an event that does not say
STATE_OF = {
    "alarm": "raised",
    "alarm_acked": "acked",
    "alarm_shelved": "shelved",
    "alarm_unshelved": "raised",
    "alarm_cleared": "cleared",
}
BODY_EVENT = "body"
LOG_EVERY_S = 10.0
TICK = "__status__"  # merged other events: {"event": TICK, "t": latest, "stopped": bool}


def is_alarm(message: dict[str, Any]) -> bool:
    return message.get("event") in ALARM_EVENTS and "id" in message and "code" in message


def is_body(message: dict[str, Any]) -> bool:
    """A body's result (app.line.body_cycle.BodyReport): one OPC UA event each."""
    return message.get("event") == BODY_EVENT


def is_kept(message: dict[str, Any]) -> bool:
    """An event the feed keeps and sends to the server process each, in order."""
    return is_alarm(message) or is_body(message)


def _tick(message: dict[str, Any], before: dict[str, Any] | None) -> dict[str, Any]:
    t = float(message.get("t", 0.0))
    stopped = message.get("event") == "stopped" or bool(message.get("stopped"))
    if before is not None:
        t, stopped = max(t, float(before["t"])), stopped or bool(before["stopped"])
    return {"event": TICK, "t": t, "stopped": stopped}


class FeedQueue(Subscription):
    """The feed's subscription (see the module docstring); `control` messages (the feed's
    own stop) are never merged nor dropped."""

    def __init__(self, maxsize: int) -> None:
        super().__init__(maxsize, drop_when_full=False, name=FEED_NAME)
        self._logged_t = -LOG_EVERY_S
        self._unlogged = 0
        self.offered = 0  # events offered so far (read with `take`)

    def take(self) -> tuple[list[dict[str, Any]], int]:
        """Everything queued, in order (waiting for the first), and the number of events
        offered up to it: a status reply taken while `offered` still equals it reflects no
        alarm change the server process has not been sent."""
        with self.not_empty:
            while not self.queue:
                self.not_empty.wait()
            batch = list(self.queue)
            self.queue.clear()
            return batch, self.offered

    def offer(self, message: dict[str, Any]) -> None:
        lost = 0
        with self.mutex:
            self.offered += 1
            if is_kept(message) or message.get("control"):
                lost = self._make_room()
                self.queue.append(message)
            elif self.queue and self.queue[-1].get("event") == TICK:
                self.queue[-1] = _tick(message, self.queue[-1])
            else:
                lost = self._make_room()
                self.queue.append(_tick(message, None))
            self.unfinished_tasks += 1
            self.not_empty.notify()
        if lost:
            self._log_lost(lost)

    def _make_room(self) -> int:
        """With the mutex held: when full, the oldest kept event dropped (the ticks around
        it merged); how many were dropped."""
        if self.maxsize <= 0 or len(self.queue) < self.maxsize:
            return 0
        q = self.queue
        for i, message in enumerate(q):
            if is_kept(message):
                del q[i]
                self.lost += 1
                if 0 < i < len(q) and q[i - 1].get("event") == TICK == q[i].get("event"):
                    q[i - 1] = _tick(q[i], q[i - 1])  # the ticks around it now adjacent
                    del q[i]
                return 1
        return 0  # ticks and control messages only: nothing worth dropping

    def _log_lost(self, n: int) -> None:
        self._unlogged += n
        now = time.monotonic()
        if now - self._logged_t < LOG_EVERY_S:
            return
        log.warning(
            "OPC UA server process behind: %d alarm or body event(s) not sent to it (%d in"
            " all; its conditions are set again from the next status reply)",
            self._unlogged,
            self.lost,
        )
        self._logged_t, self._unlogged = now, 0
