"""Writing a cell file: every section and key of a resolved configuration as TOML, read back by
`app.config.load_cell` to the same values (the commissioning writes the cell it measured).
Values are the section dataclasses' types: bool, int, float, str, a list of numbers, or a
table of lists (the spheres)."""

from __future__ import annotations

import json
import math
import re
from typing import Any

from app.config import SECTIONS, CellConfig

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(name: str) -> str:
    return name if _BARE_KEY.match(name) else json.dumps(name)


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"a cell file holds finite numbers only, got {value}")
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_key(str(k))} = {_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_value(float(v)) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to a cell file")


def dumps_cell(cfg: CellConfig, header: str = "") -> str:
    """The TOML text of every section of `cfg` (a comment `header` on top)."""
    lines = [f"# {line}" for line in header.splitlines()]
    for cls in SECTIONS:
        section = getattr(cfg, cls.name)
        lines += ["", f"[{cls.name}]"]
        # an empty string is a key's "none" (operators_group): left out, the default reads it
        lines += [f"{_key(k)} = {_value(section[k])}" for k in section if section[k] != ""]
    return "\n".join(lines).lstrip("\n") + "\n"
