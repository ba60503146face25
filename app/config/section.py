"""How a setting is declared, once: a field of a frozen section dataclass with its default and
its checks (`opt`). The section is the settings object its consumer uses and the cell file's
`[name]` table (app.config.check reads a file into it); the checks run whichever way it is
built, from a file or in code (`Section.__post_init__`), with the same words.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterator, Mapping
from dataclasses import field
from typing import Any, ClassVar


class SectionProblem(ValueError):
    """A value a section refuses: `key` and the `reason` (the reader adds file and line)."""

    def __init__(self, section: str, key: str, reason: str) -> None:
        super().__init__(f"[{section}] {key}: {reason}")
        self.key, self.reason = key, reason


def opt(
    default: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    gt: float | None = None,
    choices: tuple[str, ...] | None = None,
    n: int | None = None,
) -> Any:
    """A setting: its default and its checks (inclusive lo/hi, exclusive gt, choices, vector
    length n; numbers of a vector or a table of vectors are checked one by one)."""
    meta = {"lo": lo, "hi": hi, "gt": gt, "choices": choices, "n": n}
    if isinstance(default, list | tuple):
        return field(default=tuple(default), metadata=meta)
    if isinstance(default, dict):
        frozen = {k: tuple(v) for k, v in default.items()}
        return field(default_factory=lambda: dict(frozen), metadata=meta)
    return field(default=default, metadata=meta)


def range_problem(value: float, meta: Mapping[str, Any], what: str = "") -> str:
    """Why `value` breaks the field's range ("" when it does not)."""
    lo, hi, gt = meta.get("lo"), meta.get("hi"), meta.get("gt")
    if not math.isfinite(value):
        return f"{what}expected a finite number, got {value!r}"
    if gt is not None and not value > gt:
        return f"{what}must be > {gt:g}, got {value!r}"
    if lo is not None and value < lo:
        return f"{what}must be >= {lo:g}, got {value!r}"
    if hi is not None and value > hi:
        return f"{what}must be <= {hi:g}, got {value!r}"
    return ""


def _problem(value: Any, meta: Mapping[str, Any]) -> str:
    if isinstance(value, bool):
        return ""
    if isinstance(value, str):
        choices = meta.get("choices")
        if choices and value not in choices:
            return f"expected one of {', '.join(choices)}, got {value!r}"
        return ""
    if isinstance(value, int | float):
        return range_problem(float(value), meta)
    vectors = value.items() if isinstance(value, dict) else [("", value)]
    for label, vector in vectors:
        what = f"{label}: " if label else ""
        n = meta.get("n")
        if n is not None and len(vector) != n:
            return f"{what}expected a list of {n} numbers"
        for v in vector:
            reason = range_problem(float(v), meta, what)
            if reason:
                return reason
    return ""


class Section(Mapping[str, Any]):
    """A frozen settings dataclass that is also a read-only mapping (keys = its fields) and
    checks its values at construction. `name` is its table in the cell file; a section checks
    what spans several keys in `cross_checks`."""

    name: ClassVar[str] = ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            reason = _problem(getattr(self, f.name), f.metadata)
            if reason:
                raise SectionProblem(self.name, f.name, reason)
        for key, reason in self.cross_checks():
            raise SectionProblem(self.name, key, reason)

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        """(key, reason) of every rule between keys that the values break."""
        return iter(())

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())

    @classmethod
    def _keys(cls) -> tuple[str, ...]:
        return _field_names(cls)


@functools.cache
def _field_names(cls: type[Any]) -> tuple[str, ...]:
    """A section class's field names, read once (a mapping's every lookup asks for them)."""
    return tuple(f.name for f in dataclasses.fields(cls))


def project(cls: type[Any], section: Mapping[str, Any]) -> Any:
    """The part of a wider section that is settings class `cls` (its keys are a subset)."""
    return cls(**{f.name: section[f.name] for f in dataclasses.fields(cls)})
