"""The SCPI / IEEE 488.2 message layer of an instrument: what every conforming instrument does,
whatever its commands.

- A program message is one line; ``;`` separates program message units. A header starting with
  ``:`` starts at the root; one without it, after a ``;``, continues from the path of the previous
  command (SCPI-99 section 6.2.4); common commands (``*XXX``) leave the path alone.
- Mnemonics match case-insensitively in the short form (the capitals of ``VOLTage``) or the whole
  long form, nothing in between; nodes in brackets (``[:SOURce]``) may be left out.
- Mandatory common commands: ``*CLS``, ``*ESE``, ``*ESE?``, ``*ESR?``, ``*IDN?``, ``*OPC``,
  ``*OPC?``, ``*RST``, ``*SRE``, ``*SRE?``, ``*STB?``, ``*TST?``, ``*WAI``; ``SYSTem:ERRor[:NEXT]?``
  and ``SYSTem:VERSion?``.
- Errors go to a queue (16 entries; on overflow the last becomes -350) and set the standard
  event status register: -1xx command error (bit 5), -2xx execution error (bit 4), -3xx
  device-specific (bit 3), -4xx query error (bit 2). Numbers from SCPI-99 chapter 21: -102 syntax
  error, -104 data type error, -108 parameter not allowed, -109 missing parameter, -113 undefined
  header, -222 data out of range, -350 queue overflow.
- The responses to the queries of one message are joined with ``;`` and end with one LF.

Subclasses list their commands in ``commands``: a tuple of (pattern, handler name), a pattern in
SCPI notation such as ``"[:SOURce]:VOLTage[:LEVel][:IMMediate][:AMPLitude]"``. A handler gets
(query: bool, params: list[str]) and returns the response of a query (None for a command); it
raises ``ScpiError(code, message)``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import ClassVar

QUEUE_SIZE = 16
ERRORS = {
    -102: "Syntax error",
    -104: "Data type error",
    -108: "Parameter not allowed",
    -109: "Missing parameter",
    -113: "Undefined header",
    -222: "Data out of range",
    -350: "Queue overflow",
}
_NRF = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_MNEMONIC = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


class ScpiError(Exception):
    def __init__(self, code: int, message: str = "") -> None:
        super().__init__(code, message)
        self.code, self.message = code, message or ERRORS.get(code, "Error")


@dataclass(frozen=True)
class _Node:
    short: str
    long: str
    optional: bool

    def matches(self, word: str) -> bool:
        w = word.upper()
        return w in (self.short, self.long)


def _nodes(pattern: str) -> list[_Node]:
    nodes = []
    for optional, name in re.findall(r"(\[)?:([A-Za-z]+)\]?", pattern):
        short = "".join(c for c in name if c.isupper() or c.isdigit())
        nodes.append(_Node(short, name.upper(), bool(optional)))
    return nodes


def _match(nodes: list[_Node], words: list[str]) -> bool:
    """Whether ``words`` spell the pattern, optional nodes left out or not."""
    if not nodes:
        return not words
    head, rest = nodes[0], nodes[1:]
    if words and head.matches(words[0]) and _match(rest, words[1:]):
        return True
    return head.optional and _match(rest, words)


def parse_number(text: str, minimum: float, maximum: float, default: float) -> float:
    """A <numeric value>: NRf, optionally with the unit V or MV, or MIN / MAX / DEF."""
    word = text.strip().upper()
    keywords = {"MIN": minimum, "MINIMUM": minimum, "MAX": maximum, "MAXIMUM": maximum}
    keywords |= {"DEF": default, "DEFAULT": default}
    if word in keywords:
        return keywords[word]
    scale = 1.0
    if word.endswith("MV"):
        word, scale = word[:-2].strip(), 1e-3
    elif word.endswith("V"):
        word = word[:-1].strip()
    if not _NRF.match(word):
        raise ScpiError(-104)
    return float(word) * scale


class ScpiInstrument:
    """The message layer; subclasses add ``commands`` and implement ``identity`` and
    ``reset()``."""

    commands: ClassVar[tuple[tuple[str, str], ...]] = ()
    identity = "rvis,ScpiInstrument,0,1.0"

    def __init__(self) -> None:
        self.error_queue: list[tuple[int, str]] = []
        self.esr = 0
        self.ese = 0
        self.sre = 0
        self._tree = [(_nodes(p), h) for p, h in self._all_commands()]

    def _all_commands(self) -> list[tuple[str, str]]:
        return [
            (":SYSTem:ERRor[:NEXT]", "_system_error"),
            (":SYSTem:VERSion", "_system_version"),
            *self.commands,
        ]

    def reset(self) -> None:
        """``*RST``: the device's settings to their defaults (the queue is left alone)."""

    def key_of(self, handler: str) -> str:
        """A short name for a command's handler (for test hooks), e.g. ``SYST:ERR``."""
        return {"_system_error": "SYST:ERR", "_system_version": "SYST:VERS"}.get(handler, handler)

    def before_unit(self, key: str) -> None:
        """Called with the unit's key (``SOUR:VOLT?``, ``*IDN?``) before it runs: a hook for
        fault injection; raise ScpiError to fail it."""

    # -- messages -----------------------------------------------------------------------------
    def execute(self, message: str) -> str | None:
        """Run one program message; the response message (without LF), or None if it had no
        query."""
        responses: list[str] = []
        path: list[str] = []
        for unit in message.split(";"):
            unit = unit.strip()
            if not unit:
                continue
            try:
                path, response = self._unit(unit, path)
            except ScpiError as exc:
                self.push_error(exc.code, exc.message)
                continue
            if response is not None:
                responses.append(response)
        return ";".join(responses) if responses else None

    def _unit(self, unit: str, path: list[str]) -> tuple[list[str], str | None]:
        header, rest = [*re.split(r"\s+", unit, maxsplit=1), ""][:2]
        params = [p.strip() for p in rest.split(",")] if rest.strip() else []
        query = header.endswith("?")
        bare = header[:-1] if query else header
        if bare.startswith("*"):
            self.before_unit(bare.upper() + ("?" if query else ""))
            return path, self._common(bare.upper(), query, params)
        words = bare.lstrip(":").split(":")
        if not bare.startswith(":"):
            words = path + words
        if not all(_MNEMONIC.match(w) for w in words):
            raise ScpiError(-102 if any(not w for w in words) else -113)
        for nodes, handler in self._tree:
            if _match(nodes, words):
                self.before_unit(self.key_of(handler) + ("?" if query else ""))
                return words[:-1], getattr(self, handler)(query, params)
        raise ScpiError(-113)

    def push_error(self, code: int, message: str = "") -> None:
        if len(self.error_queue) >= QUEUE_SIZE:
            self.error_queue[-1] = (-350, ERRORS[-350])
        else:
            self.error_queue.append((code, message or ERRORS.get(code, "Error")))
        bit = {1: 0x20, 2: 0x10, 3: 0x08, 4: 0x04}.get(-code // 100, 0x08)
        self.esr |= bit

    # -- IEEE 488.2 common commands -----------------------------------------------------------
    def _common(self, name: str, query: bool, params: list[str]) -> str | None:
        registers = {"*ESE": "ese", "*SRE": "sre"}
        if name in registers and not query:
            if len(params) != 1:
                raise ScpiError(-109 if not params else -108)
            value = parse_number(params[0], 0, 255, 0)
            if not (value.is_integer() and 0 <= value <= 255):
                raise ScpiError(-222)
            setattr(self, registers[name], int(value))
            return None
        if params:
            raise ScpiError(-108)
        if name in registers:
            return str(getattr(self, registers[name]))
        answers = {
            ("*IDN", True): lambda: self.identity,
            ("*OPC", True): lambda: "1",  # every command completes before the next is read
            ("*ESR", True): self._read_esr,
            ("*STB", True): self._stb,
            ("*TST", True): lambda: "0",
            ("*CLS", False): self._clear_status,
            ("*RST", False): self.reset,
            ("*OPC", False): self._set_opc,
            ("*WAI", False): lambda: None,
        }
        action = answers.get((name, query))
        if action is None:
            raise ScpiError(-113)
        result = action()
        return result if query else None

    def _read_esr(self) -> str:
        value, self.esr = self.esr, 0
        return str(value)

    def _stb(self) -> str:
        eav = 0x04 if self.error_queue else 0
        esb = 0x20 if self.esr & self.ese else 0
        return str(eav | esb)

    def _clear_status(self) -> None:
        self.error_queue.clear()
        self.esr = 0

    def _set_opc(self) -> None:
        self.esr |= 0x01

    # -- mandatory SCPI commands --------------------------------------------------------------
    def _system_error(self, query: bool, params: list[str]) -> str | None:
        if not query:
            raise ScpiError(-113)
        if params:
            raise ScpiError(-108)
        code, message = self.error_queue.pop(0) if self.error_queue else (0, "No error")
        return f'{code},"{message}"'

    def _system_version(self, query: bool, params: list[str]) -> str | None:
        if not query:
            raise ScpiError(-113)
        return "1999.0"
