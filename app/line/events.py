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
from typing import Any

from app.line.clock import Clock
from app.line.store import Store

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
        return json.dumps(out, default=str)


class EventBus:
    """emit(kind, data): one row in the events table, one log line, one message per
    subscriber (a subscriber that does not keep up loses its oldest messages, never blocks
    the service)."""

    def __init__(self, store: Store, clock: Clock, max_queue: int = 1000) -> None:
        self.store, self.clock, self.max_queue = store, clock, max_queue
        self._subs: list[queue.Queue[dict[str, Any]]] = []
        self._lock = threading.Lock()

    def subscribe(self) -> queue.Queue[dict[str, Any]]:
        q: queue.Queue[dict[str, Any]] = queue.Queue(self.max_queue)
        with self._lock:
            self._subs.append(q)
        return q

    def unsubscribe(self, q: queue.Queue[dict[str, Any]]) -> None:
        with self._lock:
            if q in self._subs:
                self._subs.remove(q)

    def emit(self, kind: str, data: dict[str, Any], *, level: int = logging.INFO) -> None:
        t = self.clock.time()
        self.store.add_event(t, kind, data)
        log.log(level, kind, extra={"event": kind, "data": data})
        message = {"event": kind, "t": t, **data}
        with self._lock:
            subs = list(self._subs)
        for q in subs:
            while True:
                try:
                    q.put_nowait(message)
                    break
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        q.get_nowait()
