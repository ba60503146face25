"""The commissioning's steps, in the order they run: each one's name (the journal's key, the
command's `next:`), its title (the prompts and the report) and the function that runs it. The
one list: the journal, the sequence and the report read it from here. A `Procedure` names such
a list with its report's title and files: the commissioning's here, the maintenance
procedures' in app/maintain/table.py, run by the same journal, sequence and report.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from app.commission import acceptance, measuring, ready, steps, stripe, workspace
from app.commission.checks import StepResult
from app.commission.context import Context
from app.line.statedir import REPORT_JSON_NAME, REPORT_MD_NAME


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
    CommissionStep("precalibration", "Pre-calibration from random views", measuring.precalibration),
    CommissionStep("plan", "Measurement plan", steps.plan),
    CommissionStep("calibration", "First calibration", measuring.calibration),
    CommissionStep(
        "acceptance",
        "Sensor acceptance (adapted from VDI/VDE 2634-2: PF, PS, SD)",
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


@dataclass(frozen=True)
class Procedure:
    """A guided procedure: its steps in order, its report's title and file names, what the
    report says once every step passed, and its journal's format."""

    steps: tuple[CommissionStep, ...]
    title: str
    report_md: str
    report_json: str
    done: str
    journal_format: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.steps)

    @property
    def titles(self) -> dict[str, str]:
        return {s.name: s.title for s in self.steps}


COMMISSIONING = Procedure(
    STEPS,
    "Commissioning report",
    REPORT_MD_NAME,
    REPORT_JSON_NAME,
    "the cell is ready for `rvis run`",
    "rvis-commission/1",
)
