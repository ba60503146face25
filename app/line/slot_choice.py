"""Which of the schedule's slots a window measures: `SlotChoice`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (as app.line.operator's
commands do); app.line.cycle.Cycle asks it for each visit of a window.

Usually the next slot of the plan that fits. A step (a knock) flagged by the drift charts is
attributed to the rigid group that moved after every window (app.line.step_handler); until it
is corrected the windows measure more slots (`slots_wanted`), those that serve the attribution
(app.line.step_fit.step_slot). A view rejected VIEW_LOST_TRIES times in a row is left out of
the windows (`view_lost` alarm) while others fit.
"""

from __future__ import annotations

from collections.abc import Sequence

from app.line.host import LineHost
from app.line.schedule import Slot
from app.line.states import AlarmCode
from app.line.step import StepStatus
from app.line.step_fit import step_slot
from app.line.step_handler import StepHandler
from app.line.store import Store
from calib.attribution import NONE, SEVERAL, step_groups

#: a schedule's view rejected this many times in a row is left out of the windows (`_seen`)
VIEW_LOST_TRIES = 3


class SlotChoice:
    """The next slot and how many a window may measure, on the service `svc`; a step being
    attributed asks `steps` for the views its correction needs."""

    def __init__(self, svc: LineHost, steps: StepHandler) -> None:
        self.svc = svc
        self.steps = steps
        self._views_lost: set[int] = set()  # slots left out by `_seen`, alarmed

    def choose(self, slots: Sequence[Slot]) -> Slot:
        """The next slot among those that fit (in the plan's order from the position): for a
        step being attributed, the one that serves it (app.line.step_fit.step_slot: the most
        informative for the group the last attribution chose, or for all of them); adaptive
        scheduling, the most informative for the sequential estimator; else the next (also
        while a corrected step's post-step measurements are gathered: the whole schedule).
        A view rejected at its last tries is left out while others fit (`_seen`)."""
        svc = self.svc
        slots = self._seen(slots)
        if self._measuring_for_step() and svc.step is not None:
            if svc.step.status in (StepStatus.CORRECTED, StepStatus.SEVERAL):
                return self._least_recent(slots)  # the full recalibration's set: every slot
            if svc.step.status == StepStatus.FOLLOWING and svc.sequential is not None:
                # the filter's candidate waits for its predicted uncertainty at every view of
                # the schedule: the slot that lowers it most (measured: the step's own slots
                # left it at 0.033 mm, above seq_max_std_mm, for the rest of an 8 h shift)
                return svc.sequential.most_informative(svc.model, slots, svc.last_visit)
            onset = svc.step.onset_id
            after = svc.store.measurements(since_id=onset - 1)
            before = svc.store.measurements(before_id=onset, last=len(svc.schedule))
            if len(after) >= len(svc.schedule) > len(before):
                # a new cell (fewer references than slots): a schedule's worth measured for
                # the attribution and no decision yet, the full recalibration's set next (in
                # the plan's order: its revisits make pairs too); a second one and still none,
                # every slot in turn, so that the set completes (no dead end)
                if len(after) >= 2 * len(svc.schedule):
                    return self._least_recent(slots)
                return slots[0]
            recent = [int(r["slot"]) for r in reversed(before)]
            lead = [g for g in step_groups(svc.model) if g.name == svc.step.choice]
            groups = lead if lead and lead[0].name not in (NONE, SEVERAL) else None
            return step_slot(
                svc.model,
                svc.x,
                slots,
                after,
                recent,
                svc.last_visit,
                groups,
                self.steps.volume_views(),
            )
        if svc.sequential is not None and svc.settings.recalib.schedule == "adaptive":
            return svc.sequential.most_informative(svc.model, slots, svc.last_visit)
        return slots[0]

    def _least_recent(self, slots: Sequence[Slot]) -> Slot:
        """Of the slots that fit, the one visited least recently (never first; in the plan's
        order from the position among equals): the schedule in turn, every slot reached.
        Taking the next in the plan's order would not do while a window measures several
        slots: a slot that fits only a window's start (a long motion) is passed over at every
        window's end and never reached, and the full recalibration's set, every slot, never
        completes (measured: a new cell's sensor knock left 12 of 24 slots unmeasured for an
        hour). A slot measured before the step comes round again too, and makes a pair."""
        ids = self.svc.visit_ids
        return min(slots, key=lambda s: ids.get(s.index, -1))

    def _seen(self, slots: Sequence[Slot]) -> Sequence[Slot]:
        """The slots not rejected VIEW_LOST_TRIES times in a row since their last good
        measurement (all of them when none is left): a view whose sphere left the sensor's
        measuring volume (a knock moved the mount or the spheres by more than the plan's
        margin) is rejected at every try, and tried again and again it takes every slot of a
        step's windows (measured: 404 rejected of 430 in a shift, the step never decided). The
        first time a view is left out a `view_lost` alarm names it and what fixes it."""
        svc = self.svc
        lost = lost_views(svc.store, svc.maintained_from_id - 1)
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

    def slots_wanted(self) -> int:
        """Slots this window may measure: more while a step is attributed (as many as fit)."""
        line = self.svc.settings.line
        if self._measuring_for_step():
            return max(line.slots_per_window, line.step_slots_per_window)
        return line.slots_per_window

    def _measuring_for_step(self) -> bool:
        """The windows measure for a flagged step (more slots): while it is attributed,
        corrected and tested; once a fast correction is shown back, or no single group
        explains the step, until the post-step measurements complete a rolling set for the
        full recalibration (measured: one slot per window left a new cell's "several" sensor
        knock 0.33 mm off for 27 windows)."""
        step = self.svc.step
        if step is None or not step.measuring:
            return False
        waits = step.status in (StepStatus.CORRECTED, StepStatus.SEVERAL)
        return not waits or self.svc.rolling_set() is None


def lost_views(store: Store, since_id: int = 0) -> set[int]:
    """The schedule's slots rejected VIEW_LOST_TRIES times in a row after measurement
    `since_id` (`SlotChoice._seen`)."""
    return set(store.rejected_in_a_row(VIEW_LOST_TRIES, since_id=since_id))
