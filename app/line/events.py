"""Events of the service: stored, logged as one JSON object per line, and streamed to the
control socket's subscribers.

`JsonLineFormatter` turns every log record into one JSON line (time, level, logger, message and
the record's `event` and `data` when present); `rvis run` installs it on stdout.
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import threading
from typing import TYPE_CHECKING, Any

from app.formats.jsontext import finite_json
from app.line.store import StorageError, Store

if TYPE_CHECKING:  # an annotation only: the socket's clients (rvis status) load no drivers
    from drivers.clock import Clock

log = logging.getLogger("rvis.line")


class JsonLineFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "t": round(record.created, 3),
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key in ("event", "data"):
            if hasattr(record, key):
                out[key] = getattr(record, key)
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(finite_json(out), default=str, allow_nan=False)


class Subscription(queue.Queue[dict[str, Any]]):
    """One subscriber's bounded queue. `drop_when_full`: a subscriber that falls `maxsize`
    events behind is dropped (`dropped` says why; no more events are queued); otherwise it
    loses its oldest events (`lost` counts them). `name`: what the bus's `lost(name)` sums."""

    def __init__(self, maxsize: int, drop_when_full: bool, name: str = "") -> None:
        super().__init__(maxsize)
        self.drop_when_full = drop_when_full
        self.dropped: str | None = None
        self.name = name
        self.lost = 0

    def offer(self, message: dict[str, Any]) -> None:
        if self.dropped is not None:
            return
        while True:
            try:
                self.put_nowait(message)
                return
            except queue.Full:
                if self.drop_when_full:
                    self.dropped = f"fell behind by {self.maxsize} events"
                    return
                with contextlib.suppress(queue.Empty):
                    self.get_nowait()
                    self.lost += 1


class EventBus:
    """emit(kind, data): one row in the events table, one log line, one message per
    subscriber (a subscriber that does not keep up is dropped or loses its oldest messages,
    never blocks the service). An event that cannot be stored (a storage fault) is still
    logged and streamed, marked `"stored": false`. publish(kind, data): the log line and the
    messages of an event the store wrote with its change (an alarm's clearing)."""

    def __init__(self, store: Store, clock: Clock, max_queue: int = 1000) -> None:
        self.store, self.clock, self.max_queue = store, clock, max_queue
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()
        self._lost: dict[str, int] = {}  # name -> events lost by its unsubscribed queues

    def subscribe(self, *, drop_when_full: bool = False, every: bool = False) -> Subscription:
        """A subscriber's queue; `every`: unbounded, for a consumer in the same process that
        must see every event (the simulated line's run, whose service can run ahead of it in
        virtual time)."""
        return self.attach(Subscription(0 if every else self.max_queue, drop_when_full))

    def attach(self, q: Subscription) -> Subscription:
        """Subscribe with a queue of the subscriber's own (a Subscription subclass with its
        own policy when full, e.g. app.line.opcua.feed.FeedQueue)."""
        with self._lock:
            self._subs.append(q)
            if q.name:
                self._lost.setdefault(q.name, 0)
        return q

    def unsubscribe(self, q: queue.Queue[dict[str, Any]]) -> None:
        with self._lock:
            if q in self._subs:
                self._subs.remove(q)
                if isinstance(q, Subscription) and q.name:
                    self._lost[q.name] += q.lost

    def lost(self, name: str) -> int | None:
        """The events lost by the queues subscribed as `name`, now and before (None: no such
        queue ever subscribed)."""
        with self._lock:
            if name not in self._lost:
                return None
            return self._lost[name] + sum(q.lost for q in self._subs if q.name == name)

    def emit(
        self, kind: str, data: dict[str, Any], *, level: int = logging.INFO, t: float | None = None
    ) -> None:
        """One event at `t` (the service's clock; default: now)."""
        t = self.clock.time() if t is None else t
        try:
            self.store.add_event(t, kind, data)
        except StorageError:
            data = {**data, "stored": False}
        self.publish(kind, data, level=level, t=t)

    def publish(
        self, kind: str, data: dict[str, Any], *, level: int = logging.INFO, t: float | None = None
    ) -> None:
        """An event the store has written already (with the change it records, in one
        transaction: an alarm's clearing, app.line.log_store.LogRecords.clear_alarms): logged
        and streamed as `emit` does, not stored again."""
        t = self.clock.time() if t is None else t
        log.log(level, kind, extra={"event": kind, "data": data})
        message = {"event": kind, "t": t, **data}
        with self._lock:
            subs = list(self._subs)
        for q in subs:
            q.offer(message)
