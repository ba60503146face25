"""Logging of the `rvis` command: chosen by the command line, never Python's last-resort handler.

The library logs to `rvis.*` loggers: the drivers (a robot abort, a lost frame, a latched fault)
and the service (every event; alarms at WARNING). With no handler anywhere, Python prints each
WARNING record bare on stderr ("alarm", "rmi://127.0.0.1:40783: abort"), lines without context
in the middle of a batch command's output. Instead:

- by default (`--log-level off`) the records go nowhere: batch commands (`rvis demo`,
  `rvis experiment shift`, `rvis run --sim --windows N`) report alarms in their summary, and the
  service (`rvis run`, `rvis run --sim` without --windows) writes its JSON-line log on stdout as
  before (app.line.launch.json_logs; stdout has JSON lines only, docs/operations.md);
- `--log-level error|warning|info|debug` prints the records of that level and above on stderr,
  one line each with the event's data (`rvis demo --log-level warning`).
"""

from __future__ import annotations

import json
import logging
import sys

LEVELS = ("off", "error", "warning", "info", "debug")

#: Marks the handler installed here, so that a second `main()` in one process replaces it.
_MARK = "_rvis_cli_handler"


class TextLineFormatter(logging.Formatter):
    """`LEVEL logger: message {data}`: the event's data (an alarm's code and message) included,
    since an event's message alone is only its kind."""

    def format(self, record: logging.LogRecord) -> str:
        line = f"{record.levelname} {record.name}: {record.getMessage()}"
        data = getattr(record, "data", None)
        if data:
            line += " " + json.dumps(data, default=str)
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


def configure(level: str = "off") -> logging.Handler:
    """Install the command's handler on the `rvis` logger (replacing an earlier one) and return
    it: a NullHandler for "off", else a handler writing text lines on stderr at `level`."""
    if level not in LEVELS:
        raise ValueError(f"log level {level!r} not in {LEVELS}")
    logger = logging.getLogger("rvis")
    for old in [h for h in logger.handlers if getattr(h, _MARK, False)]:
        logger.removeHandler(old)
    handler: logging.Handler
    if level == "off":
        handler = logging.NullHandler()  # a handler: Python's last resort stays out
    else:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(TextLineFormatter())
        handler.setLevel(level.upper())
        if logger.getEffectiveLevel() > handler.level:
            logger.setLevel(handler.level)
    setattr(handler, _MARK, True)
    logger.addHandler(handler)
    return handler
