"""Reading a TOML file for rvis: UTF-8 (a byte-order mark is accepted, as by every other reader
of rvis), parse errors with their line, and the line of every `[section] key` for messages.

`tomllib` in Python 3.11 gives a parse error's position only inside its message, and nothing
about where a valid key stands; `key_lines` scans the text for table headers and keys so that
a value that parses but is wrong can be reported at its own line.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from app.errors import InputError

_HEADER = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-\"' ]+?)\s*\]\s*(#.*)?$")
_KEY = re.compile(r"^\s*([A-Za-z0-9_\-]+|\"[^\"]*\"|'[^']*')\s*(\.\s*[A-Za-z0-9_\-\"']+\s*)*=")
_AT_LINE = re.compile(r"\(at line (\d+), column \d+\)")


def read_toml(path: str | Path) -> tuple[dict[str, Any], str]:
    """(document, text) of the TOML file at `path`; InputError naming the file (and the line of
    a syntax error) for a missing, unreadable, non-UTF-8 or invalid file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read file: {exc.strerror or exc}", file=path) from exc
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(
            f"not UTF-8 text (byte 0x{raw[exc.start]:02x})", file=path, line=line
        ) from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _AT_LINE.search(msg)
        at = int(m.group(1)) if m else None
        reason = _AT_LINE.sub("", msg).strip()
        raise InputError(f"invalid TOML: {reason}", file=path, line=at) from None


def key_lines(text: str) -> dict[tuple[str, str], int]:
    """{(section, key): line} of the first appearance of every key under a table header
    (section "" for top-level keys); 1-based lines."""
    out: dict[tuple[str, str], int] = {}
    section = ""
    for n, line in enumerate(text.splitlines(), start=1):
        if line.lstrip().startswith("#"):
            continue
        header = _HEADER.match(line)
        if header and not line.lstrip().startswith("[["):
            section = header.group(1).strip().strip("\"'")
            out.setdefault((section, ""), n)
            continue
        key = _KEY.match(line)
        if key:
            out.setdefault((section, key.group(1).strip("\"'")), n)
    return out
