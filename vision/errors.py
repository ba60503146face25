"""Errors of the vision layer: one root, a few leaves chosen by what the caller can do.

    VisionError                   root: a sweep, an image set or a file that gives no usable result
    ├── SensorFileError           a sensor-calibration file is unreadable or inconsistent
    ├── NoStripe                  no laser stripe found in any frame (blank, saturated, ...)
    ├── TooFewPoints              a stripe, but too few valid 3D points to fit a sphere
    ├── SphereFitRejected         the sphere fit failed a quality threshold (carries the quality)
    ├── CalibrationFailed         chessboards or target sweeps insufficient to calibrate the sensor
    └── FeatureRefused            a body feature's sweep gives no value (a typed reason)

Callers re-measure on NoStripe / TooFewPoints / SphereFitRejected and never use the centre;
the application layer turns these into one-line messages.
"""

from __future__ import annotations

from typing import Any


class VisionError(Exception):
    """Root of every error raised by vision/."""


class SensorFileError(VisionError):
    """A sensor-calibration file is unreadable, misses a field or holds an invalid value."""

    def __init__(self, reason: str, *, field: str | None = None) -> None:
        self.reason = reason
        self.field = field
        super().__init__(f"field '{field}': {reason}" if field else reason)


class NoStripe(VisionError):
    """No frame of the sweep holds a valid laser stripe."""


class TooFewPoints(VisionError):
    """The sweep gives fewer valid 3D points than the fit needs."""

    def __init__(self, n_points: int, n_required: int) -> None:
        self.n_points = n_points
        self.n_required = n_required
        super().__init__(f"{n_points} valid stripe points, at least {n_required} needed")


class SphereFitRejected(VisionError):
    """The sphere fit converged but failed a quality threshold; `quality` says which."""

    def __init__(self, reason: str, quality: Any = None) -> None:
        self.reason = reason
        self.quality = quality
        super().__init__(reason)


class CalibrationFailed(VisionError):
    """The calibration images or sweeps do not determine the sensor model."""


class FeatureRefused(VisionError):
    """A body feature could not be measured from its sweep; `reason` is one of REASONS (what
    failed), `detail` says by how much. Never a value: the caller stores "not measured"."""

    REASONS = ("no_points", "plane", "edge_points", "edge_coverage", "fit", "size")

    def __init__(self, reason: str, detail: str) -> None:
        if reason not in self.REASONS:
            raise ValueError(f"reason: expected one of {self.REASONS}, got {reason!r}")
        self.reason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}")
