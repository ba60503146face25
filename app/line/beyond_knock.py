"""A change beyond a knock's bounds: what the service says when it stops correcting and asks
for maintenance (app.line.jumps decides when).

A knock moves the measured spheres by up to about a millimetre and is corrected in-line. A
sensor replaced, a motor or encoder replaced or the sphere fixture renewed moves them further:
the plan's views may no longer see every sphere, and a correction from the few still seen is not
what a plant should measure bodies with. A jump larger than `[service] maintenance_step_mm` at
the measured spheres, one sphere moved alone, or `BLIND_WINDOWS` windows in a row with no sphere
where the parameters put it hold the cell in FAULT with the `maintenance` alarm (no body
measured, the interval open, no correction applied); the texts here say what moved, how much,
and which procedure fits (`rvis maintain ...`, app/maintain/), whose hand-over clears it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

#: windows in a row with every view rejected that mean the spheres are out of the sensor's
#: reach from every view the plan has (a change beyond a knock)
BLIND_WINDOWS = 3

#: the procedure that fits a group the attribution chose (app/maintain/, `rvis maintain`)
_PROCEDURE = {
    "sensor": "rvis maintain sensor",
    "fixture": "rvis maintain fixture",
}
_EVENT = {
    "sensor": "a sensor replaced or re-mounted",
    "fixture": "the sphere fixture renewed or the part frame moved",
}


@dataclass(frozen=True)
class MaintenanceNeed:
    """What the `maintenance` alarm says: its text, and the same as fields stored beside it
    (the alarm's `detail`, which app.line.maintenance_state reads: never parsed back out of
    the text): `what` moved (a clause), the `procedures` that fit (commands), the `group`
    named ("" when none is: more than one thing, or no sphere seen), the change at the
    measured spheres [mm] (None: not known)."""

    text: str
    what: str
    procedures: tuple[str, ...]
    group: str = ""
    moved_mm: float | None = None

    def detail(self) -> dict[str, Any]:
        return {
            "what": self.what,
            "procedures": list(self.procedures),
            "group": self.group,
            "moved_mm": self.moved_mm,
        }


def _axis(group: str) -> str:
    """The axis of a joint group ("J3", "J2-encoder" -> "3", "2"; "" otherwise)."""
    head = group.split("-")[0]
    return head[1:] if head.startswith("J") and head[1:].isdigit() else ""


def procedure_of(group: str) -> str:
    """The `rvis maintain` command for an attributed group ("J3" -> axis 3)."""
    if _axis(group):
        return f"rvis maintain axis {_axis(group)}"
    return _PROCEDURE.get(group, "")


def event_of(group: str) -> str:
    if _axis(group):
        return f"the motor or encoder of axis {_axis(group)} replaced (its zero moved)"
    return _EVENT.get(group, "")


def several_need(visible_mm: float, bound_mm: float, found: str = "") -> MaintenanceNeed:
    """The need for a change beyond a knock no one group explains."""
    what = (
        f"a change of {visible_mm:.2f} mm at the measured spheres, beyond a knock's {bound_mm:g} mm"
        + (f": {found}" if found else "")
    )
    procedures = ("rvis commission --restart", "rvis maintain sensor|axis N|fixture")
    text = (
        f"{what}; not one group: more than one thing changed;"
        f" bodies are not measured with this cell: commission again (`{procedures[0]}`), or run"
        f" the maintenance procedure of what was done to the cell (`{procedures[1]}`)"
    )
    return MaintenanceNeed(text, what, procedures, "", visible_mm)


#: what a 6-DoF group's own size ("3.205 mm / 0.9910 deg") is, said beside it: it is not
#: the move at the measured spheres, the figure the bound is on (near one point of the field
#: of view a sensor's shift and tilt are confounded; their effect at the spheres is not)
_OWN_TERMS = {
    "sensor": "the sensor frame's shift at its origin / its tilt, as fitted",
    "fixture": "the part frame's shift at its origin / its turn, as fitted",
}


def change_need(
    group: str, label: str, found: str, size: str, visible_mm: float, bound_mm: float
) -> MaintenanceNeed:
    """The need for a change of one group (`label`) beyond a knock, each magnitude once and
    said what it is: `size` the change in the group's own terms (a 6-DoF group's shift / turn
    named as such), `visible_mm` the move of the measured spheres (what the bound `bound_mm`
    is on); `found` what the test found beyond them (the measurements it rests on), left out
    where it repeats `size`. `what` carries both figures."""
    own = f" ({_OWN_TERMS.get(group, 'its shift / turn')})" if " mm / " in size else ""
    extra = f", {found}" if found and size not in found else ""
    what = (
        f"likely {event_of(group)}: {label} moved {size}{own},"
        f" {visible_mm:.2f} mm at the measured spheres where a knock moves them at most"
        f" {bound_mm:g} mm{extra}"
    )
    procedure = procedure_of(group)
    text = (
        f"a change beyond a knock; {what}; bodies are not measured with this cell: run"
        f" `{procedure}`"
    )
    return MaintenanceNeed(text, what, (procedure,) if procedure else (), group, visible_mm)


def sphere_moved_need(
    name: str, moved_mm: float, evidence: str, bound_mm: float
) -> MaintenanceNeed:
    """The need when one sphere moved alone by `moved_mm`."""
    bound = "beyond a knock's" if moved_mm > bound_mm else "within a knock's"
    what = (
        f"sphere {name} moved {moved_mm:.2f} mm on its own ({evidence}), {bound} {bound_mm:g}"
        " mm: the sphere knocked, replaced or its stand moved"
    )
    procedure = "rvis maintain fixture"
    text = f"{what}; the cell's reference is no longer where it was measured: run `{procedure}`"
    return MaintenanceNeed(text, what, (procedure,), name, moved_mm)


def blind_need(windows: int, rejected: int) -> MaintenanceNeed:
    """The need when no view sees its sphere any more."""
    what = (
        f"no sphere seen where the parameters put it in {windows} windows in a row ({rejected}"
        " views rejected or off by more than a knock): the"
        " spheres are more than the measuring volume from where the parameters put them, a"
        " change far beyond a knock (an axis's motor or encoder replaced, a sensor replaced,"
        " the fixture moved)"
    )
    procedures = ("rvis maintain axis N", "rvis maintain sensor", "rvis maintain fixture")
    text = (
        f"{what}; bodies are not measured with this cell: run the maintenance"
        f" procedure of what was done (`{procedures[0]}`, `{procedures[1]}`, `{procedures[2]}`),"
        " or commission again"
    )
    return MaintenanceNeed(text, what, procedures)
