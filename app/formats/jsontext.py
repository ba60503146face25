"""Strict JSON text (never NaN or Infinity, which JSON does not have and jq refuses): the one
conversion, for the files rvis writes (app.formats.files), `--json` outputs and the service's
JSON log lines (app.line.events). Light: no numerics imported."""

from __future__ import annotations

import json
import math
from typing import Any


def finite_json(data: Any) -> Any:
    """`data` with every NaN or infinite float replaced by None (JSON has no such numbers)."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: finite_json(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [finite_json(v) for v in data]
    return data


def dumps_json(data: Any, indent: int | None = None) -> str:
    """Strict JSON text: never NaN or Infinity."""
    return json.dumps(finite_json(data), indent=indent, allow_nan=False)
