"""A change beyond a knock's bounds (issue 41): when the service stops correcting and asks for
maintenance, and what it says.

A knock (a sensor mount nudged by tenths of a millimetre, a fixture bumped, an encoder zero
slipping by hundredths of a degree) moves the measured spheres by up to about a millimetre:
the service attributes it and corrects it in-line (app/line/step_handler.py). A maintenance
event moves them further: a sensor replaced (a new mount pose of millimetres, its own camera
and laser), a motor or encoder replaced (a zero off by up to a degree: centimetres at the
spheres), a sphere fixture renewed (spheres millimetres from where they stood). The plan's
views then no longer see every sphere (the measuring volume's depth is +-5 mm), a fast
correction from a handful of measurements of the views still seen is not what a plant should
measure bodies with, and the new sensor's own calibration is not something the spheres can
give. So:

- a step attributed and seen larger than `[service] maintenance_step_mm` at the measured
  spheres (noise removed, `visible_step_mm`),
- one sphere seen moved by more than the bound on its own since the flag (`sphere_alone`:
  each of its residuals above the bound, the other spheres' within a third of it: a sphere
  replaced, which no kinematic group explains; said at once, without waiting for pairs), or
- `BLIND_WINDOWS` windows in a row in which no view saw its sphere where the parameters put
  it (each rejected, or off by more than the bound: too far, or too few, for an attribution)

hold the cell in FAULT with the `maintenance` alarm (a fault code: the PLC's fault bit is set,
bodies are not measured with this cell), the step's suspect interval open from its last
trustworthy measurement, no correction applied, and the text says what moved, how much, and
which procedure fits (`rvis maintain ...`, app/maintain/). The procedure's hand-over clears
the alarm and closes the interval at its new version.
"""

from __future__ import annotations

import math

from calib.attribution import NONE, SEVERAL, Attribution

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


def beyond(a: Attribution, visible_mm: float, bound_mm: float) -> bool:
    """Whether an attributed step is beyond a knock: seen larger than the bound (whatever
    group moved, or several)."""
    return a.choice != NONE and visible_mm > bound_mm


def step_text(a: Attribution, visible_mm: float, bound_mm: float) -> str:
    """The `maintenance` alarm's text for a step beyond a knock: in an operator's words (the
    attribution's BIC and chi2 stay in its event's JSON, `Attribution.to_json`)."""
    fit = a.chosen
    n = f"{a.n} measurement{'s' * (a.n != 1)}"
    if a.choice == SEVERAL or fit is None:
        return several_text(visible_mm, bound_mm, f"no one group explains the {n}")
    if len(fit.group.params) == 6:
        size = f"{fit.translation_mm:.2f} mm / {fit.rotation_deg:.3f} deg"
    else:
        size = ", ".join(
            f"{name} {math.degrees(v):+.4f} deg"
            for name, v in zip(fit.group.params, fit.step, strict=True)
        )
    return change_text(fit.group.name, fit.group.label, n, size, visible_mm, bound_mm)


def several_text(visible_mm: float, bound_mm: float, found: str = "") -> str:
    """The `maintenance` alarm's text for a change beyond a knock no one group explains."""
    head = (
        f"a change of {visible_mm:.2f} mm at the measured spheres, beyond a knock's {bound_mm:g} mm"
    )
    return (
        f"{head}{': ' + found if found else ''}; not one group: more than one thing changed;"
        " bodies are not measured with this cell: commission again (`rvis commission"
        " --restart`), or run the maintenance procedure of what was done to the cell (`rvis"
        " maintain sensor|axis N|fixture`)"
    )


#: what a 6-DoF group's own size ("3.205 mm / 0.9910 deg") is, said beside it: it is not
#: the move at the measured spheres, the figure the bound is on (near one point of the field
#: of view a sensor's shift and tilt are confounded; their effect at the spheres is not)
_OWN_TERMS = {
    "sensor": "the sensor frame's shift at its origin / its tilt, as fitted",
    "fixture": "the part frame's shift at its origin / its turn, as fitted",
}


def change_text(
    group: str, label: str, found: str, size: str, visible_mm: float, bound_mm: float
) -> str:
    """The `maintenance` alarm's text for a change of one group (`label`) beyond a knock, each
    magnitude once and said what it is: `size` the change in the group's own terms (a 6-DoF
    group's shift / turn named as such), `visible_mm` the move of the measured spheres (what
    the bound `bound_mm` is on); `found` what the test found beyond them (the measurements it
    rests on), left out where it repeats `size`. The `likely ...` clause carries both figures
    (app.line.maintenance_state reads it)."""
    own = f" ({_OWN_TERMS.get(group, 'its shift / turn')})" if " mm / " in size else ""
    extra = f", {found}" if found and size not in found else ""
    return (
        f"a change beyond a knock; likely {event_of(group)}: {label} moved {size}{own},"
        f" {visible_mm:.2f} mm at the measured spheres where a knock moves them at most"
        f" {bound_mm:g} mm{extra}; bodies are not measured with this cell: run"
        f" `{procedure_of(group)}`"
    )


#: measurements of the other spheres since the flag that show one sphere moved alone (that
#: they did not move with it)
MIN_OTHER_MEASUREMENTS = 2


def sphere_alone(residuals_mm: dict[str, list[float]], bound_mm: float) -> str | None:
    """The sphere that moved beyond a knock's bound on its own, from the residuals [mm] of each
    sphere's measurements since the flag (with the parameters in force): every one of its own
    above the bound, every other sphere's within a third of it (MIN_OTHER_MEASUREMENTS of them
    at least); or None."""
    moved = [t for t, v in residuals_mm.items() if v and min(v) > bound_mm]
    others = [e for t, v in residuals_mm.items() if t not in moved for e in v]
    if len(moved) != 1 or len(others) < MIN_OTHER_MEASUREMENTS or max(others) >= bound_mm / 3:
        return None
    return moved[0]


def sphere_text(name: str, residuals_mm: dict[str, list[float]], bound_mm: float) -> str:
    """The `maintenance` alarm's text when one sphere moved alone."""
    own = residuals_mm[name]
    others = max(e for t, v in residuals_mm.items() if t != name for e in v)
    evidence = f"{len(own)} measurements; the other spheres within {others:.2f} mm"
    return sphere_moved_text(name, sum(own) / len(own), evidence, bound_mm)


def sphere_moved_text(name: str, moved_mm: float, evidence: str, bound_mm: float) -> str:
    """The `maintenance` alarm's text when one sphere moved alone by `moved_mm`."""
    bound = "beyond a knock's" if moved_mm > bound_mm else "within a knock's"
    return (
        f"sphere {name} moved {moved_mm:.2f} mm on its own ({evidence}), {bound} {bound_mm:g}"
        " mm: the sphere knocked, replaced or its stand moved; the cell's reference is no"
        " longer where it was measured: run `rvis maintain fixture`"
    )


def blind_text(windows: int, rejected: int) -> str:
    """The `maintenance` alarm's text when no view sees its sphere any more."""
    return (
        f"no sphere seen where the parameters put it in {windows} windows in a row ({rejected}"
        " views rejected or off by more than a knock): the"
        " spheres are more than the measuring volume from where the parameters put them, a"
        " change far beyond a knock (an axis's motor or encoder replaced, a sensor replaced,"
        " the fixture moved); bodies are not measured with this cell: run the maintenance"
        " procedure of what was done (`rvis maintain axis N`, `rvis maintain sensor`, `rvis"
        " maintain fixture`), or commission again"
    )
