"""One sphere measurement: a galvo sweep (frames + mirror commands) -> centre in the sensor frame.

    frames --extract_sweep--> stripe pixels --triangulate_sweep--> 3D points --fit_sphere--> centre

This is the function the simulated cell and `rvis sensor measure` call.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vision.errors import NoStripe
from vision.sensor_model import SensorModel
from vision.spherefit import FitQuality, FitThresholds, fit_sphere
from vision.stripe import StripeSettings, extract_sweep
from vision.triangulate import triangulate_sweep

F64 = NDArray[np.float64]
CERTIFIED_RADIUS_MM = 15.0


@dataclass(frozen=True, eq=False)
class SphereMeasurement:
    """c_sensor_mm shape=(3,) [mm] in S; cov_mm2 shape=(3, 3) [mm^2]; radius_mm used for the
    centre (certified, or the free fit); quality of the fit; n_frames_used (frames with stripe
    points); stripe rejections summed over the sweep; status "ok" (rejections raise)."""

    c_sensor_mm: F64
    cov_mm2: F64
    radius_mm: float
    quality: FitQuality
    n_frames_used: int
    n_saturated: int
    n_multi_peak: int
    n_too_wide: int
    status: str = "ok"


def measure_sphere_from_sweep(
    frames: Sequence[NDArray[np.generic]] | NDArray[np.generic],
    mirror_commands_v: Sequence[float] | F64,
    sensor_model: SensorModel,
    *,
    certified_radius_mm: float | None = CERTIFIED_RADIUS_MM,
    mode: str = "fast",
    stripe_settings: StripeSettings | None = None,
    thresholds: FitThresholds | None = None,
) -> SphereMeasurement:
    """Measure a sphere's centre from one sweep.

    frames: n images shape=(H, W), uint8 or uint16 (12 bit), one per mirror command;
    mirror_commands_v: shape=(n,) galvo commands [V] as sent to the DAC;
    sensor_model: the calibrated sensor; certified_radius_mm: the sphere's certified radius
    (None: report the free-radius fit); mode: "fast" (windowed centroid) or "precise" (Steger).
    Returns a SphereMeasurement with the centre in the sensor frame S.
    Raises NoStripe (no frame holds a valid stripe), TooFewPoints, SphereFitRejected, or
    ValueError for inconsistent inputs (frame count vs commands, wrong image size).
    """
    cmds = np.asarray(mirror_commands_v, dtype=np.float64)
    if len(frames) != len(cmds):
        raise ValueError(f"{len(frames)} frames but {len(cmds)} mirror commands")
    cam = sensor_model.camera
    for i, f in enumerate(frames):
        if f.shape != (cam.height_px, cam.width_px):
            raise ValueError(
                f"frame {i} has shape {f.shape}, the sensor model expects "
                f"{(cam.height_px, cam.width_px)}"
            )
    stripes = extract_sweep(frames, mode, stripe_settings)
    n_sat = sum(s.n_saturated for s in stripes)
    n_multi = sum(s.n_multi_peak for s in stripes)
    n_wide = sum(s.n_too_wide for s in stripes)
    if sum(len(s) for s in stripes) == 0:
        raise NoStripe(
            f"no valid stripe in {len(frames)} frames (rows rejected: {n_sat} "
            f"saturated, {n_multi} multi-peak, {n_wide} too wide)"
        )
    X, _ = triangulate_sweep(stripes, cmds, sensor_model)
    fit = fit_sphere(X, certified_radius_mm, thresholds)
    return SphereMeasurement(
        c_sensor_mm=fit.centre_mm,
        cov_mm2=fit.cov_mm2,
        radius_mm=fit.radius_mm,
        quality=fit.quality,
        n_frames_used=sum(1 for s in stripes if len(s) > 0),
        n_saturated=n_sat,
        n_multi_peak=n_multi,
        n_too_wide=n_wide,
    )
