"""The wire trace: what went over the wire to every device, for the day a device answers
unexpectedly (like pyserial's ``spy://``, for every protocol back end at once).

One seam for every back end: a back end's transport calls its ``TraceChannel`` (``tx`` for a
request, ``rx`` for a reply, ``note`` for an error or an event) and the channel writes one JSON
line to the process's ``WireTrace`` file:

    {"t": 1234.567891, "dev": "robot", "dir": ">", "msg": "{\\"Command\\":\\"FRC_GetStatus\\"}"}

``t`` is ``time.monotonic()`` [s] (every file starts with a header line giving the wall-clock
time of a monotonic instant, so a printer can show both); ``dir`` is ``>`` sent, ``<`` received,
``!`` an error or event (a timeout, a lost connection, a frame). What each back end writes:
RMI and tracker JSON lines as sent and received, Modbus function, address and words, SCPI
lines, the camera's GenICam calls (feature writes and reads) and frame events.

Off by default and free when off: a device's ``trace`` is None and every call site is one
``if trace is not None`` test (bench/trace.py measures it). It is switched on per device by the
URL option ``?trace=1`` or for every device by the cell file's ``[devices] trace = true``; the
application owns the file (``StateDir.wire_trace``) and hands it to ``drivers.registry``. The
file rotates at ``max_bytes`` and keeps ``keep`` old files (``wire.jsonl.1`` the newest).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivers.errors import DeviceConfigError

FORMAT = "rvis-wire/1"
SENT, RECEIVED, NOTE = ">", "<", "!"
MAX_MSG = 4096  # longer messages are cut (a camera payload is never traced)


class WireTrace:
    """A rotating JSON-lines trace file shared by the devices of one process (thread-safe).

    ``every_device``: trace every device opened with it (``[devices] trace = true``), not only
    those whose URL says ``?trace=1``."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        max_bytes: int = 10 * 2**20,
        keep: int = 5,
        every_device: bool = False,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """clock: the monotonic time of each line [s] (read under the lock, so that lines from
        several writers land in the order of their times)."""
        if max_bytes < 1024 or keep < 1:
            raise DeviceConfigError(f"trace needs max_bytes >= 1024 and keep >= 1 ({path})")
        self.path = Path(path)
        self.max_bytes, self.keep, self.every_device = int(max_bytes), int(keep), every_device
        self._lock = threading.Lock()
        self._clock = clock
        self._file: Any = None
        self._size = 0

    def channel(self, device: str, name: str = "") -> TraceChannel:
        """The channel of one device (``device``: its family); notes which device it is."""
        channel = TraceChannel(self, device)
        channel.note(f"traced: {name or device}")
        return channel

    def write(self, device: str, direction: str, message: str) -> None:
        if len(message) > MAX_MSG:
            message = f"{message[:MAX_MSG]}... ({len(message)} chars)"
        with self._lock:
            record = {"t": round(self._clock(), 6), "dev": device, "dir": direction}
            line = json.dumps(record | {"msg": message}, separators=(",", ":")) + "\n"
            data = line.encode("utf-8", errors="replace")
            if self._file is None or self._size + len(data) > self.max_bytes:
                self._start_file(rotate=self._file is not None)
            self._file.write(data)
            self._file.flush()  # a crash keeps everything up to the last exchange
            self._size += len(data)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def __enter__(self) -> WireTrace:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _start_file(self, *, rotate: bool) -> None:
        if self._file is not None:
            self._file.close()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if rotate or (self.path.exists() and self.path.stat().st_size >= self.max_bytes):
            self._rotate()
        self._file = open(self.path, "ab")  # noqa: SIM115 (held open between writes)
        self._size = self._file.tell()
        header = {"t": round(self._clock(), 6), "wall": time.time(), "format": FORMAT}
        data = (json.dumps(header | {"pid": os.getpid()}) + "\n").encode()
        self._file.write(data)
        self._size += len(data)

    def _rotate(self) -> None:
        """wire.jsonl -> wire.jsonl.1 -> ... -> wire.jsonl.<keep> (the oldest is dropped)."""
        for i in range(self.keep - 1, 0, -1):
            older = self.path.with_name(f"{self.path.name}.{i}")
            if older.exists():
                os.replace(older, self.path.with_name(f"{self.path.name}.{i + 1}"))
        if self.path.exists():
            os.replace(self.path, self.path.with_name(f"{self.path.name}.1"))


class TraceChannel:
    """One device's side of the trace: ``tx`` what was sent, ``rx`` what came back, ``note``
    anything else (an error, a frame event)."""

    __slots__ = ("device", "trace")

    def __init__(self, trace: WireTrace, device: str) -> None:
        self.trace, self.device = trace, device

    def tx(self, message: str) -> None:
        self.trace.write(self.device, SENT, message)

    def rx(self, message: str) -> None:
        self.trace.write(self.device, RECEIVED, message)

    def note(self, message: str) -> None:
        self.trace.write(self.device, NOTE, message)
