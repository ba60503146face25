"""The OPC UA server's log of refused connections (docs/opcua.md "Isolation"): every refusal
counted, few lines however many peers are refused.

`REFUSALS.note(host, text, kind)` counts a refusal by its kind (`counts`) and logs at most one
line per peer host per LOG_EVERY_S, with the number refused from that host meanwhile, and at
most LOG_LINES_MAX lines per LOG_EVERY_S from all peers together: beyond LOG_LINES_MAX - 1 hosts
in one such window the others' refusals are summed up in one line when the window is over
(from the server's event loop; without one, at the next refusal after it), naming the hosts
refused most. So 19 addresses refused without a pause write 4 lines per 10 s, not 19.

`QuietAsyncua` (on the server process's log handler) sends asyncua's own records of a peer's
connection ("Refusing connection from %s: at max_connections=%s") here too, and lets its other
records through at most once per message per LOG_EVERY_S.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import Counter

log = logging.getLogger("rvis.line.opcua")

LOG_EVERY_S = 10.0
LOG_LINES_MAX = 4  # refusal lines per LOG_EVERY_S from all peers together (one a summary)
SUMMARY_HOSTS = 5  # hosts named in a summary line (the most refused)
MAX_KEYS = 1024  # throttled keys kept (beyond: the quiet ones forgotten)


class Throttle:
    """At most one line per key per LOG_EVERY_S: `due(key)` is None while it is quiet, else the
    number of lines held back since the last one."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, int]] = {}

    def due(self, key: str) -> int | None:
        now = time.monotonic()
        last, quiet = self._last.get(key, (-math.inf, 0))
        if now - last < LOG_EVERY_S:
            self._last[key] = (last, quiet + 1)
            return None
        self._last[key] = (now, 0)
        if len(self._last) > MAX_KEYS:  # many keys: forget the quiet ones
            self._last = {k: v for k, v in self._last.items() if now - v[0] < LOG_EVERY_S}
        return quiet


class RefusalLog:
    """Every refusal counted by its kind (`counts`); one log line per peer host per
    LOG_EVERY_S (with how many were refused meanwhile), and LOG_LINES_MAX lines per LOG_EVERY_S
    at most in all (the hosts beyond summed up in one line)."""

    def __init__(self) -> None:
        self._throttle = Throttle()
        self.counts: Counter[str] = Counter()
        self._window_t = -math.inf  # when the window of LOG_EVERY_S began
        self._lines = 0  # host lines in it
        self._untold: Counter[str] = Counter()  # refusals by host beyond its lines

    def note(self, host: str, text: str, kind: str = "refused") -> None:
        self.counts[kind] += 1
        now = time.monotonic()
        if now - self._window_t >= LOG_EVERY_S:
            self._summarise(now)
            self._window_t, self._lines = now, 0
        if host in self._untold:  # summed up when the window is over
            self._untold[host] += 1
            return
        quiet = self._throttle.due(host)
        if quiet is None:
            return
        if self._lines >= LOG_LINES_MAX - 1:  # the window's lines are spent: summed up after
            if not self._untold:
                self._summary_at(self._window_t + LOG_EVERY_S - now)
            if len(self._untold) < MAX_KEYS:
                self._untold[host] += 1 + quiet
            return
        self._lines += 1
        more = f" ({quiet} more refused from {host} in the last {LOG_EVERY_S:g} s)" if quiet else ""
        log.warning("OPC UA connection from %s refused: %s%s", host, text, more)

    def _summary_at(self, delay_s: float) -> None:
        """The summary line when the window is over, from the running event loop (none: the
        next refusal after it writes it)."""
        with contextlib.suppress(RuntimeError):
            asyncio.get_running_loop().call_later(max(delay_s, 0.0) + 0.01, self._window_over)

    def _window_over(self) -> None:
        now = time.monotonic()
        if now - self._window_t >= LOG_EVERY_S:
            self._summarise(now)

    def _summarise(self, now: float) -> None:
        """One line for the refusals of the window just over that had no line of their own."""
        if not self._untold:
            return
        hosts = [h for h, _ in self._untold.most_common(SUMMARY_HOSTS)]
        others = len(self._untold) - len(hosts)
        named = ", ".join(hosts) + (f" and {others} more" if others else "")
        late_s = now - (self._window_t + LOG_EVERY_S)  # the summary waits for a refusal
        window = f"{LOG_EVERY_S:g} s"
        when = f"the last {window}" if late_s < 1 else f"the {window} to {late_s:.0f} s ago"
        n = len(self._untold)
        log.warning(
            "OPC UA connections refused from %d more address%s in %s: %d refused in all (%s)",
            n,
            "" if n == 1 else "es",
            when,
            sum(self._untold.values()),
            named,
        )
        self._untold.clear()


REFUSALS = RefusalLog()


def host_of(peer: object) -> str:
    """The host of a peer address ((host, port, ...) or a string)."""
    return str(peer[0]) if isinstance(peer, tuple) and peer else str(peer)


class QuietAsyncua(logging.Filter):
    """asyncua's records in the server process, rate-limited like the guard's: one about a
    peer's connection (its first argument the peer's address, as in "Refusing connection from
    %s: at max_connections=%s") goes to REFUSALS; any other at most once per message per
    LOG_EVERY_S, with the number held back."""

    def __init__(self) -> None:
        super().__init__()
        self._throttle = Throttle()

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.name.startswith("asyncua"):
            return True
        args = record.args if isinstance(record.args, tuple) else ()
        if args and isinstance(args[0], tuple):
            REFUSALS.note(host_of(args[0]), f"asyncua: {record.getMessage()}", "asyncua")
            return False
        quiet = self._throttle.due(f"{record.name}:{record.msg}")
        if quiet is None:
            return False
        if quiet:
            record.msg = (
                f"{record.getMessage()} ({quiet} more like it in the last {LOG_EVERY_S:g} s)"
            )
            record.args = None
        return True
