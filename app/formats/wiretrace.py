"""Reading and printing a wire trace (drivers/trace.py writes it): `rvis devices trace FILE`.

Each record is printed on one line with the wall-clock time (from the file's header, which ties
a monotonic instant to the wall clock), the seconds since the first record, the device, the
direction (``>`` sent, ``<`` received, ``!`` error or event) and the message; a reply also shows
the round trip since that device's last request:

    10:41:07.012345  +  0.000412  robot    <  127.0.0.1:40211 {"Command": ...}  [0.38 ms]
"""

from __future__ import annotations

import datetime as dt
import json
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


def format_records(records: Iterable[TraceRecord]) -> Iterator[str]:
    """Printable lines (see the module docstring)."""
    first: float | None = None
    sent: dict[str, float] = {}
    for r in records:
        first = r.t if first is None else first
        clock = "" if r.wall is None else dt.datetime.fromtimestamp(r.wall).strftime("%H:%M:%S.%f")
        rtt = ""
        if r.direction == SENT:
            sent[r.device] = r.t
        elif r.direction == RECEIVED and r.device in sent:
            rtt = f"  [{(r.t - sent.pop(r.device)) * 1e3:.2f} ms]"
        yield f"{clock:15}  +{r.t - first:10.6f}  {r.device:8} {r.direction}  {r.message}{rtt}"


def to_json(r: TraceRecord) -> str:
    return json.dumps(
        {"t": r.t, "wall": r.wall, "dev": r.device, "dir": r.direction, "msg": r.message}
    )
