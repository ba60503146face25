"""The maintenance procedures' steps, in order (app/maintain/__init__.py): the one list per
event, run by the commissioning's journal, sequence and report (app/commission/table.py
`Procedure`)."""

from __future__ import annotations

from app.commission import acceptance, steps
from app.commission.table import CommissionStep, Procedure
from app.line.statedir import MAINTENANCE_REPORT_JSON, MAINTENANCE_REPORT_MD
from app.maintain import fixture, handover, reidentify, workspace
from app.maintain import steps as m

EVENTS = ("sensor", "axis", "fixture")

_DEVICES = CommissionStep("devices", "Devices answer, the cell commissioned", m.devices)
_PREPARE = CommissionStep("prepare", "The version in force, plan, sensor and spheres", m.prepare)
_WORKSPACE = CommissionStep(
    "workspace",
    "Validation at workspace positions against the tracker (the paper's)",
    workspace.workspace,
)
_HANDOVER = CommissionStep("handover", "Handed back to `rvis run`", handover.handover)

_STEPS = {
    "sensor": (
        _DEVICES,
        _PREPARE,
        CommissionStep("sensor", "The new sensor's calibration", steps.sensor),
        CommissionStep(
            "handeye", "The sensor's mount on the spheres (hand-eye)", reidentify.reidentify
        ),
        CommissionStep(
            "acceptance",
            "Sensor acceptance (adapted from VDI/VDE 2634-2: PF, PS, SD)",
            acceptance.acceptance_step,
        ),
        _WORKSPACE,
        _HANDOVER,
    ),
    "axis": (
        _DEVICES,
        _PREPARE,
        CommissionStep("zero", "The axis's zero, from one view", m.zero),
        CommissionStep("reidentify", "The axis's zero on the spheres", reidentify.reidentify),
        _WORKSPACE,
        _HANDOVER,
    ),
    "fixture": (
        _DEVICES,
        _PREPARE,
        CommissionStep(
            "spheres", "Sphere positions from the tracker, again", fixture.spheres_moved
        ),
        CommissionStep(
            "reidentify", "The plan at the spheres' places; the part frame", reidentify.reidentify
        ),
        _WORKSPACE,
        _HANDOVER,
    ),
}

_TITLES = {
    "sensor": "a sensor replaced",
    "axis": "a motor or encoder replaced on axis {axis}",
    "fixture": "the sphere fixture renewed",
}


def procedure(event: str, axis: int | None = None) -> Procedure:
    """The procedure of an event ("sensor", "axis" with its axis, "fixture")."""
    title = _TITLES[event].format(axis=axis)
    return Procedure(
        _STEPS[event],
        f"Maintenance report: {title}",
        MAINTENANCE_REPORT_MD,
        MAINTENANCE_REPORT_JSON,
        "the cell is handed back to `rvis run`",
        "rvis-maintain/1",
    )
