"""Loading a calibration or validation data set from the two CSV files, with every calib
error about the data translated into an InputError that names the measurements file."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from app.errors import InputError
from app.formats.files import match_targets, read_measurements, read_targets
from calib.errors import CalibError
from calib.identify import Measurements
from calib.robot import JointLimits

T = TypeVar("T")


def load_dataset(
    measurements: str | Path, targets: str | Path, limits: JointLimits | None = None
) -> Measurements:
    """The measurements matched to their targets."""
    return load_dataset_lines(measurements, targets, limits)[0]


def load_dataset_lines(
    measurements: str | Path, targets: str | Path, limits: JointLimits | None = None
) -> tuple[Measurements, list[int]]:
    """(the measurements matched to their targets, the file line of each measurement)."""
    targets_path = Path(targets)
    rows = read_measurements(measurements, limits)
    centres = match_targets(rows, read_targets(targets_path), targets_path)
    m = Measurements(rows.q_deg, rows.c_sensor_mm, centres, tuple(rows.targets), rows.temp_c)
    return m, rows.lines


def as_input_error(path: str | Path, work: Callable[[], T]) -> T:
    """Run `work`; a CalibError (bad or degenerate data) becomes an InputError naming path."""
    try:
        return work()
    except CalibError as exc:
        raise InputError(str(exc), file=path) from exc
