"""The laser stripe as the camera sees it: the robot looks at the first sphere (a view planned
on the nominal model, the sphere in the middle of the field of view), the galvo at 0 V, and
the camera grabs one frame at each exposure of `[commission] exposures_us`. Per exposure, the
stripe's quality numbers (vision.stripe): rows with a valid stripe point, the median peak as
a fraction of full scale, the rows rejected as saturated, the median RMS width. The chosen
exposure is the one with the most valid rows among those within the limits (then the peak
nearest half scale); it goes into the cell file `rvis run` reads ([camera] exposure_us). The
region of interest is where the stripe falls over the sweep (its first, middle and last
command), reported for the camera's set-up; the measurements use full frames.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from app.commission.checks import (
    StepResult,
    at_least,
    at_most,
    holds,
    within,
)
from app.commission.context import Context
from app.commission.files import STRIPE_FILE, STRIPE_IMAGE_FILE
from app.formats.files import write_json
from app.formats.sweeps import write_image
from calib import candidates
from drivers.camera import Camera, CameraSettings
from vision.stripe import StripePoints, extract_stripe

#: Views around the sphere: straight down +-30 deg, the sphere in the middle of the field.
VIEW_TILT_DEG = 30.0


def stripe(ctx: Context) -> StepResult:
    r = StepResult()
    camera, galvo = ctx.station.camera, ctx.station.galvo
    if camera is None or galvo is None:
        r.checks.append(holds("camera and galvo configured", False))
        return r
    name, q = first_view(ctx)
    r.results["view"] = {"sphere": name, "q_deg": q.tolist()}
    ctx.home()  # from home, as every commissioning motion
    ctx.move(q, f"a view of sphere {name}")
    wanted = camera.settings
    chosen = wanted
    try:
        galvo.set_volts(0.0)
        rows = [_at_exposure(camera, wanted, e) for e in ctx.cfg.commission.exposures_us]
        best = choose(rows, ctx)
        chosen = dataclasses.replace(wanted, exposure_us=best["exposure_us"])
        camera.configure(chosen)
        roi, frame = _region(camera, galvo, ctx)
        write_image(ctx.path(STRIPE_IMAGE_FILE), frame)
    finally:
        galvo.set_volts(0.0)
        camera.configure(chosen)
    ctx.home()
    c = ctx.cfg.commission
    r.results |= {"exposures": rows, "chosen": best, "region_px": roi}
    write_json(ctx.path(STRIPE_FILE), r.results)
    r.files += [STRIPE_FILE, STRIPE_IMAGE_FILE]
    r.checks += [
        at_least("stripe rows", best["rows"], c.min_stripe_rows),
        at_most(
            "saturated rows", 100 * best["saturated_fraction"], 100 * c.max_saturated_fraction, "%"
        ),
        within(
            "stripe peak, of full scale",
            100 * best["peak_fraction"],
            100 * c.min_peak_fraction,
            100 * c.max_peak_fraction,
            "%",
        ),
        at_most("stripe width (RMS)", best["width_px"], c.max_stripe_width_px, "px"),
    ]
    return r


def first_view(ctx: Context) -> tuple[str, Any]:
    """The first sphere of the cell file and a reachable view of it near home (nominal model,
    the sphere 130 mm in front, in the middle of the field of view)."""
    model = ctx.cfg.model()
    name, p = next(iter(ctx.cfg.spheres_part_mm.items()))
    rng = np.random.default_rng([ctx.cfg.commission.seed, 17])
    views = candidates.random_configurations(
        model,
        model.nominal_x(),
        p,
        24,
        rng,
        max_offset_mm=(0.0, 0.0, 0.0),
        max_tilt_deg=VIEW_TILT_DEG,
    )
    if not len(views.q_deg):
        raise RuntimeError(f"no reachable view of sphere {name}")
    home = np.asarray(ctx.line.home_deg)
    nearest = int(np.argmin(np.max(np.abs(views.q_deg - home), axis=1)))
    return name, views.q_deg[nearest]


def stripe_numbers(points: StripePoints, top: int) -> dict[str, float]:
    """The quality numbers of one frame's stripe (see the module docstring)."""
    n = len(points)
    rejected = n + points.n_saturated
    return {
        "rows": n,
        "peak_fraction": float(np.median(points.peak_dn)) / top if n else 0.0,
        "saturated_fraction": points.n_saturated / rejected if rejected else 0.0,
        "multi_peak_rows": points.n_multi_peak,
        "width_px": float(np.median(points.width_px)) if n else float("inf"),
    }


def _at_exposure(camera: Camera, settings: CameraSettings, exposure_us: float) -> dict[str, Any]:
    applied = camera.configure(dataclasses.replace(settings, exposure_us=exposure_us))
    image = camera.grab().image
    top = 255 if image.dtype == np.uint8 else 4095
    numbers = stripe_numbers(extract_stripe(image), top)
    return {"exposure_us": applied.exposure_us, **numbers}


def choose(rows: list[dict[str, Any]], ctx: Context) -> dict[str, Any]:
    """The exposure with the most valid rows within the limits (peak nearest half scale among
    equals); the most rows overall when none is within them (the checks then fail)."""
    c = ctx.cfg.commission

    def within(row: dict[str, Any]) -> bool:
        return bool(
            row["saturated_fraction"] <= c.max_saturated_fraction
            and c.min_peak_fraction <= row["peak_fraction"] <= c.max_peak_fraction
            and row["width_px"] <= c.max_stripe_width_px
        )

    pool = [row for row in rows if within(row)] or rows
    return max(pool, key=lambda row: (row["rows"], -abs(row["peak_fraction"] - 0.5)))


def _region(camera: Camera, galvo: Any, ctx: Context) -> tuple[list[int], Any]:
    """(x, y, width, height) [px] holding the stripe at the sweep's first, middle and last
    command (a margin of min_roi_margin_px, clipped to the sensor), and the middle frame."""
    commands = ctx.sweep.commands_v()
    us, vs, middle = [], [], None
    for volts in (commands[0], 0.0, commands[-1]):
        galvo.set_volts(volts)
        image = camera.grab().image
        points = extract_stripe(image)
        us.append(points.u_px)
        vs.append(points.v_px)
        middle = image if volts == 0.0 else middle
    u, v = np.concatenate(us), np.concatenate(vs)
    w, h = camera.sensor_size()
    if not len(u):
        return [0, 0, w, h], middle
    m = ctx.cfg.commission.min_roi_margin_px
    x0, y0 = max(0, int(u.min()) - m), max(0, int(v.min()) - m)
    x1, y1 = min(w, int(np.ceil(u.max())) + m + 1), min(h, int(np.ceil(v.max())) + m + 1)
    return [x0, y0, x1 - x0, y1 - y0], middle
