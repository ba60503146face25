"""A cell the service runs without a commissioning, as the status reply says it (`uncommissioned`
in app.line.status): the parameters in force came from no calibration of this cell (the
state directory's first version made of the nominal model, or of a file given with `rvis run
--params`, app.line.startup), so its U95 is what the measurements on them show (millimetres)
until the first calibration: when that comes, in good measurements and about how many windows.

    uncommissioned(svc) -> None | {"text", "measurements_needed", "windows_needed"}
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from app.line.host import LineHost
from app.line.params_store import INITIAL_SOURCE
from app.line.slot_choice import slots_wanted


def uncommissioned(svc: LineHost) -> dict[str, Any] | None:
    """None when a calibration of this cell is in force (a commissioning's, an in-line one, a
    maintenance's); else when the first one comes (module docstring)."""
    if _identified(svc.params.version_path(svc.version)):
        return None
    needed: int | None = None
    if svc.recalibrator.busy or svc.decision.recal_ids is not None:
        text = "the first calibration is running"
    elif svc.decision.pending_calibration is not None:
        text = (
            f"the first calibration (calibration {svc.decision.pending_calibration}) waits for an"
            " engineer's approve"
        )
    elif svc.sequential is not None:
        text = "the sequential estimator proposes the first calibration as the views are measured"
    else:
        r = svc.settings.recalib
        rolling = r.rolling_n + r.holdout_size - int(svc.store.counts().get("ok", 0))
        due = 0 if svc.decision.force_recal else r.every_n - svc.decision.new_since_recal
        needed = max(rolling, due, 0)
        if needed:
            text = (
                f"the first calibration comes after {needed} more good measurements (about"
                f" {_windows(svc, needed)} windows)"
            )
        else:  # as many as it needs, but the set may still lack a sphere or a view
            text = f"the first calibration {svc.recal_wait() or 'comes after the next window'}"
    return {
        "text": text,
        "measurements_needed": needed,
        "windows_needed": None if needed is None else _windows(svc, needed),
    }


def _windows(svc: LineHost, measurements: int) -> int:
    """About how many windows, at the slots a window measures now (app.line.slot_choice;
    at most: fewer may fit a window's time)."""
    return math.ceil(measurements / slots_wanted(svc))


_IDENTIFIED: dict[Path, bool] = {}  # a version's file never changes


def _identified(path: Path) -> bool:
    """The version file at `path` holds a calibration of this cell: anything but the start's
    initial parameters without an identification's residuals (not readable: said to be, so
    that nothing is claimed)."""
    if path not in _IDENTIFIED:
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return True
        source = (doc.get("provenance") or {}).get("source")
        _IDENTIFIED[path] = source != INITIAL_SOURCE or bool(doc.get("residuals"))
    return _IDENTIFIED[path]
