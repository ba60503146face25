"""Reading and printing a wire trace (drivers/trace.py writes it): `rvis devices trace FILE`.

Each record is printed on one line with the wall-clock time (from the file's header, which ties
a monotonic instant to the wall clock), the seconds since the first record, the device, the
direction (``>`` sent, ``<`` received, ``!`` error or event) and the message; a reply also shows
the round trip since that device's last request:

    10:41:07.012345  +  0.000412  robot    <  127.0.0.1:40211 {"Command": ...}  [0.38 ms]

Polls that changed nothing are folded (`fold=True`, the default of `rvis devices trace`; `--all`
prints every record): an exchange (a request and the device's reply right after it) is a
repeat when the same device's previous exchange of the same shape (the request with its
numbers masked) had the same request and the same reply, but for counters: a number that
went up where it went up at least twice before and never down (the heartbeats of PLC and
service, learnt from their first steps; a status word that goes up and down never is). A run
of repeats prints as one line with the count of lines folded, where the first would have been:

                              plc      .  (1722 lines of plc polls: nothing changed but counters)

The first exchange of each shape, and any exchange in which a value changed (the window bit,
busy, a joint angle), prints in full; the order of the printed lines is the file's.
"""

from __future__ import annotations

import datetime as dt
import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from app.errors import InputError
from drivers.trace import FORMAT, NOTE, RECEIVED, SENT

DIRECTIONS = (SENT, RECEIVED, NOTE)


@dataclass(frozen=True)
class TraceRecord:
    """One record: monotonic time [s], device family, direction, message; the wall-clock time
    [s since the epoch] when the file's header gives it."""

    t: float
    device: str
    direction: str
    message: str
    wall: float | None = None


def rotated(path: Path) -> list[Path]:
    """The rotated predecessors of a trace file, oldest first, then the file itself."""
    older = []
    i = 1
    while (p := path.with_name(f"{path.name}.{i}")).exists():
        older.append(p)
        i += 1
    return [*reversed(older), path]


def read_records(path: Path) -> Iterator[TraceRecord]:
    """The records of one trace file; InputError naming the line of anything else."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the trace: {exc}", file=path) from None
    offset: float | None = None  # wall - monotonic, from the latest header
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            doc = json.loads(line)
            if "format" in doc:
                if doc["format"] != FORMAT:
                    raise InputError(f"not a {FORMAT} trace", file=path, line=n, field="format")
                offset = float(doc["wall"]) - float(doc["t"])
                continue
            t, direction = float(doc["t"]), str(doc["dir"])
            device, message = str(doc["dev"]), str(doc["msg"])
        except (json.JSONDecodeError, TypeError, KeyError, ValueError) as exc:
            raise InputError(f"not a trace record ({exc})", file=path, line=n) from None
        if direction not in DIRECTIONS:
            raise InputError(f"unknown direction {direction!r}", file=path, line=n, field="dir")
        yield TraceRecord(t, device, direction, message, None if offset is None else t + offset)


_NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


def _shape(message: str) -> tuple[str, list[str]]:
    """The message with its numbers masked, and the numbers."""
    return _NUMBER.sub("#", message), _NUMBER.findall(message)


class _Folder:
    """Decides which exchanges repeat the previous one of their shape (module docstring).

    A number that differs is a counter's when its place (device, shape, request or reply,
    position) has gone up at least twice before and never down: a heartbeat is learnt from
    its first two steps, while a status word that goes up and down (the window bit) or a
    value seen to change once is never taken for one."""

    def __init__(self) -> None:
        self.last: dict[tuple[str, str], tuple[list[str], str, list[str]]] = {}
        self.trend: dict[tuple[str, str, str, int], tuple[int, bool]] = {}  # ups, ever down

    def _same(self, place: tuple[str, str, str], before: list[str], now: list[str]) -> bool:
        """Equal but for counters; `learn`: count the steps of each place."""
        if len(before) != len(now):
            return False
        for i, (a, b) in enumerate(zip(before, now, strict=True)):
            if a == b:
                continue
            ups, down = self.trend.get((*place, i), (0, False))
            if not (ups >= 2 and not down and _is_int(a) and _is_int(b) and int(b) > int(a)):
                return False
        return True

    def _learn(self, place: tuple[str, str, str], before: list[str], now: list[str]) -> None:
        if len(before) != len(now):
            return
        for i, (a, b) in enumerate(zip(before, now, strict=True)):
            if a != b:
                ups, down = self.trend.get((*place, i), (0, False))
                up = _is_int(a) and _is_int(b) and int(b) > int(a)
                self.trend[(*place, i)] = (ups + up, down or not up)

    def request_repeats(self, r: TraceRecord) -> bool:
        """The request repeats its shape's previous one (its reply decides the rest)."""
        shape, numbers = _shape(r.message)
        before = self.last.get((r.device, shape))
        return before is not None and self._same((r.device, shape, ">"), before[0], numbers)

    def exchange(self, request: TraceRecord, reply: TraceRecord) -> bool:
        """Record a complete exchange; whether it repeats its shape's previous one."""
        shape, numbers = _shape(request.message)
        reply_shape, reply_numbers = _shape(reply.message)
        before = self.last.get((request.device, shape))
        self.last[(request.device, shape)] = (numbers, reply_shape, reply_numbers)
        if before is None:
            return False
        req, rep = (request.device, shape, ">"), (request.device, shape, "<")
        repeats = (
            self._same(req, before[0], numbers)
            and before[1] == reply_shape
            and self._same(rep, before[2], reply_numbers)
        )
        self._learn(req, before[0], numbers)
        if before[1] == reply_shape:
            self._learn(rep, before[2], reply_numbers)
        return repeats


def _is_int(text: str) -> bool:
    return text.lstrip("-").isdigit()


def format_records(records: Iterable[TraceRecord], fold: bool = False) -> Iterator[str]:
    """Printable lines (see the module docstring); `fold`: polls that changed nothing as
    one line per run."""
    first: float | None = None
    sent: dict[str, float] = {}
    folder = _Folder()
    held: TraceRecord | None = None  # a request that may start a repeat, until its reply
    folded: dict[str, int] = {}  # device -> lines folded since the last line printed

    def line(r: TraceRecord) -> str:
        nonlocal first
        first = r.t if first is None else first
        clock = "" if r.wall is None else dt.datetime.fromtimestamp(r.wall).strftime("%H:%M:%S.%f")
        rtt = ""
        if r.direction == SENT:
            sent[r.device] = r.t
        elif r.direction == RECEIVED and r.device in sent:
            rtt = f"  [{(r.t - sent.pop(r.device)) * 1e3:.2f} ms]"
        return f"{clock:15}  +{r.t - first:10.6f}  {r.device:8} {r.direction}  {r.message}{rtt}"

    def flush() -> Iterator[str]:
        """Before a line is printed: the counts of what was folded, and a held request."""
        nonlocal held
        for device, n in folded.items():
            what = f"({n} lines of {device} polls: nothing changed but counters)"
            yield f"{'':15}  {'':11}  {device:8} .  {what}"
        folded.clear()
        if held is not None:
            asked[held.device] = held
            yield line(held)
            held = None

    asked: dict[str, TraceRecord] = {}  # the printed request of each device, until its reply
    for r in records:
        if not fold:
            yield line(r)
            continue
        if held is not None and r.device == held.device and r.direction == RECEIVED:
            request, held = held, None
            if folder.exchange(request, r):
                folded[r.device] = folded.get(r.device, 0) + 2
                continue
            yield from flush()
            yield line(request)
            yield line(r)
            continue
        if r.direction == SENT and folder.request_repeats(r):
            if held is not None:  # two requests in a row: the first one prints as it is
                yield from flush()
            held = r
            continue
        yield from flush()
        if r.direction == SENT:
            asked[r.device] = r
        elif r.direction == RECEIVED and r.device in asked:
            folder.exchange(asked.pop(r.device), r)
        yield line(r)
    yield from flush()


def to_json(r: TraceRecord) -> str:
    return json.dumps(
        {"t": r.t, "wall": r.wall, "dev": r.device, "dir": r.direction, "msg": r.message}
    )
