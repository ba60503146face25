"""The fixture's spheres in a maintenance procedure (app/maintain/__init__.py): measured again by
the tracker, or, with none at hand, located by the robot with the version in force."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from app.commission.checks import StepResult, at_least, at_most
from app.commission.context import Context
from app.commission.files import PARAMS_BEFORE_FILE, TARGETS_BEFORE_FILE, TARGETS_FILE
from app.commission.measuring import measure_views
from app.formats.files import read_targets, write_targets
from app.formats.params import from_json
from app.maintain.views import Views


def spheres_located(ctx: Context) -> StepResult:
    """A fixture renewed with no tracker at hand: each sphere located by the robot with the
    version in force, from every view the plan has of it (aimed where the cell file had it:
    a renewal moves a sphere by millimetres, within the measuring volume), its place the mean
    of the views' centres in the part frame. The places carry the version in force's error at
    those views and nothing independent checks them: the robot and the sensor did not change,
    so the cell keeps the accuracy it had, and the workspace validation does not run
    (NO_TRACKER). Checked: every sphere seen from two views or more, its views agreeing within
    `[commission] max_target_rms_mm` (RMS about their mean), near the cell file's place."""
    c = ctx.cfg.commission
    model, x = from_json(ctx.path(PARAMS_BEFORE_FILE))
    views = Views.of_plan(ctx)
    taken = measure_views(
        ctx,
        list(zip(views.targets, views.q_deg, strict=True)),
        ctx.sphere_sensor(ctx.sensor_model()),
        "locate the spheres:",
    )
    temps = None if any(t is None for t in taken.temp_c) else np.array(taken.temp_c, float)
    points = model.points_part(
        x, np.array(taken.q_deg).reshape(-1, 6), np.array(taken.c_sensor_mm).reshape(-1, 3),
        temp_c=temps,
    )  # fmt: skip
    before = read_targets(ctx.path(TARGETS_BEFORE_FILE))
    r = StepResult()
    r.results["source"] = "located by the robot with the version in force (no tracker)"
    r.results["spheres"], positions, moved = {}, {}, {}
    for t in before:
        mine = points[[k for k, s in enumerate(taken.targets) if s == t]]
        r.checks.append(at_least(f"{t} seen from", len(mine), 2, "views"))
        if len(mine) < 2:
            continue
        p = mine.mean(axis=0)
        spread = float(np.sqrt(np.mean(np.sum((mine - p) ** 2, axis=1))))
        positions[t], moved[t] = p, float(np.linalg.norm(p - before[t]))
        x_mm, y_mm, z_mm = map(float, p)
        r.results["spheres"][t] = {
            "x_mm": x_mm, "y_mm": y_mm, "z_mm": z_mm, "views": len(mine), "rms_mm": spread,
            "offset_mm": moved[t],
        }  # fmt: skip
        r.checks.append(
            at_most(f"{t} views' RMS about their mean", spread, c.max_target_rms_mm, "mm")
        )
        r.checks.append(at_most(f"{t} from the cell file", moved[t], c.max_sphere_offset_mm, "mm"))
    r.results["moved_mm"] = moved
    r.results["rejected"] = taken.rejected
    if len(positions) == len(before):
        write_targets(ctx.path(TARGETS_FILE), positions)
        r.files.append(TARGETS_FILE)
    return r


def without_tracker(fields: dict[str, Any]) -> dict[str, Any]:
    """A procedure's context fields with the cell's tracker left out (`--no-tracker`: none at
    hand today; the fixture's spheres are then located by the robot)."""
    return fields | {"station": dataclasses.replace(fields["station"], tracker=None)}


def spheres_moved(ctx: Context) -> StepResult:
    """The commissioning's spheres step (the tracker measures them again, TARGETS_FILE), and
    how far each moved from where the cell file had it; with no tracker at hand (none in the
    station and no export), the spheres located by the robot (`spheres_located`)."""
    from app.commission.steps import spheres

    if ctx.targets_file is None and ctx.station.tracker is None:
        return spheres_located(ctx)
    r = spheres(ctx)
    if not ctx.path(TARGETS_FILE).is_file():
        return r
    before = read_targets(ctx.path(TARGETS_BEFORE_FILE))
    now = read_targets(ctx.path(TARGETS_FILE))
    moved = {t: float(np.linalg.norm(now[t] - before[t])) for t in now if t in before}
    r.results["moved_mm"] = moved
    r.checks.append(at_least("spheres measured again", len(moved), len(before)))
    return r
