"""Reading one cell-file table into its section (app.config.section): the type from the
annotation, the range, choices and vector length from the field's metadata, then the section's
own checks. Every failure is an InputError `file:line: [section] key: reason`."""

from __future__ import annotations

import dataclasses
import difflib
import logging
import math
from pathlib import Path
from typing import Any, get_type_hints

from app.config.section import SectionProblem, range_problem
from app.errors import InputError

_log = logging.getLogger("rvis.config")


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


class SectionReader:
    """Builds section dataclasses from a parsed cell file; knows each key's line."""

    def __init__(self, path: str, lines: dict[tuple[str, str], int]) -> None:
        self.path, self.lines = path, lines

    def fail(self, section: str, key: str, reason: str) -> InputError:
        line = self.lines.get((section, key), self.lines.get((section, "")))
        return InputError(f"[{section}] {key}: {reason}", file=self.path, line=line)

    def unknown_section(self, name: str, known: tuple[str, ...]) -> InputError:
        hint = _hint(name, known)
        line = self.lines.get((name, ""))
        return InputError(f"[{name}]: unknown section{hint}", file=self.path, line=line)

    def section(self, cls: Any, values: dict[str, Any]) -> Any:
        fields = {f.name: f for f in dataclasses.fields(cls)}
        hints = get_type_hints(cls)
        out: dict[str, Any] = {}
        retired: dict[str, str] = getattr(cls, "retired", {})
        for key, value in values.items():
            if key in retired and key not in fields:
                line = self.lines.get((cls.name, key))
                at = f"{self.path}:{line}" if line else self.path
                _log.warning("%s: [%s] %s is no longer read (%s)", at, cls.name, key, retired[key])
                continue
            if key not in fields:
                raise self.fail(cls.name, key, "unknown key" + _hint(key, tuple(fields)))
            out[key] = self._value(cls.name, key, value, hints[key], fields[key].metadata)
        try:
            return cls(**out)
        except SectionProblem as exc:  # a rule between keys (Section.cross_checks)
            raise self.fail(cls.name, exc.key, exc.reason) from None

    def _value(self, section: str, key: str, value: Any, kind: Any, meta: Any) -> Any:
        text = str(kind)
        if kind is bool:
            if not isinstance(value, bool):
                raise self.fail(section, key, f"expected true or false, got {value!r}")
            return value
        if kind is str:
            return self._string(section, key, value, meta)
        if kind is int:
            if not isinstance(value, int) or isinstance(value, bool):
                raise self.fail(section, key, f"expected an integer, got {value!r}")
            self._range(section, key, value, meta)
            return value
        if kind is float:
            return self._number(section, key, value, meta)
        if text.startswith("dict"):
            if not isinstance(value, dict) or not value:
                raise self.fail(section, key, "expected a table of ids -> [x, y, z]")
            return {str(k): self._vector(section, key, v, meta, f"{k}: ") for k, v in value.items()}
        return self._vector(section, key, value, meta, "")

    def _string(self, section: str, key: str, value: Any, meta: Any) -> str:
        if not isinstance(value, str):
            raise self.fail(section, key, f"expected a string, got {value!r}")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise self.fail(
                section,
                key,
                f"expected one of {', '.join(choices)}, got {value!r}" + _hint(value, choices),
            )
        if not choices and not value.strip():
            raise self.fail(section, key, "expected a non-empty string")
        return value

    def _number(self, section: str, key: str, value: Any, meta: Any, what: str = "") -> float:
        if not _is_number(value):
            raise self.fail(section, key, f"{what}expected a number, got {value!r}")
        if not math.isfinite(value):
            raise self.fail(section, key, f"{what}expected a finite number, got {value!r}")
        self._range(section, key, value, meta, what)
        return float(value)

    def _vector(
        self, section: str, key: str, value: Any, meta: Any, what: str
    ) -> tuple[float, ...]:
        n = meta.get("n")
        if not isinstance(value, list) or (n is not None and len(value) != n):
            raise self.fail(section, key, f"{what}expected a list of {n} numbers")
        return tuple(self._number(section, key, v, meta, what) for v in value)

    def _range(self, section: str, key: str, value: float, meta: Any, what: str = "") -> None:
        reason = range_problem(value, meta, what)
        if reason:
            raise self.fail(section, key, reason)


def _hint(word: str, known: tuple[str, ...]) -> str:
    close = difflib.get_close_matches(word, known, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def in_cell_file(exc: InputError, path: str | Path | None) -> InputError:
    """A problem found with a cell file's setting after it was read (a group that does not
    exist on this machine, `[service] engineers_group`) located in the file: its path and the
    setting's line; `exc` itself when it names a file already or is not a setting's."""
    import re

    from app.config.tomlfile import key_lines

    m = re.fullmatch(r"\[(\w+)\] (\w+)", exc.field or "")
    if exc.file is not None or m is None or path is None:
        return exc
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError:
        return exc
    line = key_lines(text).get((m.group(1), m.group(2)))
    if line is None:
        return exc
    return InputError(f"[{m.group(1)}] {m.group(2)}: {exc.reason}", file=path, line=line)
