"""Which of the schedule's slots a window measures: `SlotChoice`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do); app.line.cycle.Cycle asks it for each visit of a window.

The next slot of the plan that fits (with adaptive scheduling, the one most informative for the
sequential estimator); more of them in a window while a jump is not corrected yet
(`slots_wanted`). A view rejected VIEW_LOST_TRIES times in a row is left out of the windows
(`view_lost` alarm) while others fit.
"""

from __future__ import annotations

from collections.abc import Sequence

from app.line.host import LineHost
from app.line.schedule import Slot
from app.line.states import AlarmCode
from app.line.store import Store

#: a schedule's view rejected this many times in a row is left out of the windows (`_seen`)
VIEW_LOST_TRIES = 3


class SlotChoice:
    """The next slot and how many a window may measure, on the service `svc`."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self._views_lost: set[int] = set()  # slots left out by `_seen`, alarmed

    def choose(self, slots: Sequence[Slot]) -> Slot:
        """The next slot among those that fit (in the plan's order from the position); with
        adaptive scheduling, the most informative for the sequential estimator. A view rejected
        at its last tries is left out while others fit (`_seen`)."""
        svc = self.svc
        slots = self._seen(slots)
        if svc.sequential is not None and svc.settings.recalib.schedule == "adaptive":
            return svc.sequential.most_informative(svc.model, slots, svc.decision.last_visit)
        return slots[0]

    def _seen(self, slots: Sequence[Slot]) -> Sequence[Slot]:
        """The slots not rejected VIEW_LOST_TRIES times in a row since their last good
        measurement (all of them when none is left): a view whose sphere left the sensor's
        measuring volume (a knock moved the mount or the spheres by more than the plan's
        margin) is rejected at every try, and tried again and again it takes the windows' slots
        from the views that still see their spheres. The first time a view is left out a
        `view_lost` alarm names it and what fixes it."""
        svc = self.svc
        lost = lost_views(svc.store, svc.decision.maintained_since_id())
        if not lost:
            return slots
        new = sorted(set(lost) - self._views_lost)
        if new:
            self._views_lost |= set(new)
            names = ", ".join(f"{i} ({svc.schedule.slots[i].target})" for i in new)
            svc.alarm(
                AlarmCode.VIEW_LOST,
                f"schedule slot {names} rejected {VIEW_LOST_TRIES} times in a row: left out of"
                " the windows; the sphere is no longer where the plan saw it (a knock, a moved"
                " sphere): re-plan with `rvis plan` and restart, or commission again",
                "low",
            )
        return [s for s in slots if s.index not in lost] or slots


def slots_wanted(svc: LineHost) -> int:
    """Slots a window of the service `svc` may measure now: `[line] slots_per_window`; while
    a jump found by the one estimator has its episode open (not corrected yet, or corrected
    and not yet confirmed, or its group watched for a refinement: app.line.jumps) or a full
    recalibration is wanted (a change no single group explains, an accuracy the cell
    cannot vouch for, an engineer's "calibrate now"), up to `[line] step_slots_per_window`
    (those that fit the window's time): the correction's evidence, or the schedule's cycle for
    the full one, in fewer windows."""
    line = svc.settings.line
    # from a jump found until its episode is over: its correction's evidence, then the
    # measurements that confirm or refine it (app.line.jumps: the interval's close, the
    # group's watch), in fewer windows
    if svc.decision.episode is not None or svc.decision.force_recal:
        return max(line.step_slots_per_window, line.slots_per_window)
    return line.slots_per_window


def lost_views(store: Store, since_id: int = 0) -> set[int]:
    """The schedule's slots rejected VIEW_LOST_TRIES times in a row after measurement
    `since_id` (`SlotChoice._seen`)."""
    return set(store.rejected_in_a_row(VIEW_LOST_TRIES, since_id=since_id))
