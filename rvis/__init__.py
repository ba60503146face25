"""The rvis Python API (docs/api.md) under a name of its own:

    from rvis import Calibration, command_xyzwpr

    cal = Calibration.load("params.json")
    p_part_mm = cal.to_part(q_deg, p_sensor_mm)

This is `app.api` (with the few types its users need), loaded so that it cannot collide with a
program's own packages: the project's top-level packages (app, calib, ...) have generic names,
so `rvis` loads the API's modules under `rvis._impl` (rvis/_isolated.py) and never imports or
registers a module called `app`, `calib`, `vision`, `drivers` or `fakes`. A program with its
own `app` package imports `rvis` and its own `app` side by side, in either order.
"""

from __future__ import annotations as _annotations

import typing as _typing

__all__ = [
    "MODEL_NAME",
    "MODEL_VERSION",
    "Calibration",
    "Compensation",
    "CompensationSettings",
    "InputError",
    "command_xyzwpr",
    "load_parameters",
]

if _typing.TYPE_CHECKING:  # the same objects, as the type checker sees them
    from app.api import MODEL_NAME, MODEL_VERSION, Calibration, command_xyzwpr, load_parameters
    from app.errors import InputError
    from calib.compensate import Compensation, CompensationSettings
else:
    from rvis._isolated import load as _load

    _api = _load("app.api")
    MODEL_NAME, MODEL_VERSION = _api.MODEL_NAME, _api.MODEL_VERSION
    Calibration, command_xyzwpr = _api.Calibration, _api.command_xyzwpr
    load_parameters = _api.load_parameters
    InputError = _load("app.errors").InputError
    Compensation = _load("calib.compensate").Compensation
    CompensationSettings = _load("calib.compensate").CompensationSettings
