"""The commissioning's steps, in the order they run: each one's name (the journal's key, the
command's `next:`), its title (the prompts and the report) and the function that runs it. The
one list: the journal, the sequence and the report read it from here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from app.commission import acceptance, measuring, ready, steps, stripe, workspace
from app.commission.checks import StepResult
from app.commission.context import Context


@dataclass(frozen=True)
class CommissionStep:
    """One step: its name, its title and what runs it."""

    name: str
    title: str
    run: Callable[[Context], StepResult]


STEPS = (
    CommissionStep("devices", "Devices answer", steps.devices),
    CommissionStep("stripe", "Laser stripe seen by the camera", stripe.stripe),
    CommissionStep("sensor", "Sensor calibration", steps.sensor),
    CommissionStep("spheres", "Sphere positions from the tracker", steps.spheres),
    CommissionStep("plan", "Measurement plan", steps.plan),
    CommissionStep("calibration", "First calibration", measuring.calibration),
    CommissionStep(
        "acceptance",
        "Sensor acceptance (VDI/VDE 2634-2: PF, PS, SD)",
        acceptance.acceptance_step,
    ),
    CommissionStep(
        "validation",
        "Quick check: the calibration spheres from new views",
        measuring.validation,
    ),
    CommissionStep(
        "workspace",
        "Validation at workspace positions against the tracker (the paper's)",
        workspace.workspace_validation,
    ),
    CommissionStep("ready", "State directory ready for `rvis run`", ready.ready),
)
NAMES = tuple(s.name for s in STEPS)
TITLES = {s.name: s.title for s in STEPS}
