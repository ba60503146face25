"""The service's handling of a step (a knock) between its flag and its correction:
`StepHandler`, a collaborator of app.line.service.Service that sees it as app.line.host.LineHost
(as app.line.operator's commands do).

The flag (app.line.recording) opens a suspect interval and a `Step` (app.line.step); after every
window the step is attributed (calib.attribution through app.line.step.correct_step, at the
change point located by `locate_step`) and, batch estimator, its group's fast correction applied
or proposed when its gates pass; the sequential estimator widens the attributed group's
covariance instead. A correction trained after the change point in force (Versions.in_force ->
`corrected`), the interval closes when the held-out residuals with it are back (`check_recovery`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from app.errors import InputError
from app.formats.params import carried_from_json
from app.line.accuracy import AFTER_STEP, PREDICTED, VOUCHED, document_seed, evidence
from app.line.beyond_knock import BLIND_WINDOWS, beyond, sphere_alone, sphere_text, step_text
from app.line.drift import OVERALL
from app.line.host import LineHost
from app.line.states import AlarmCode, suspect_json
from app.line.step import Step, StepStatus, recovery_under, step_alarm_text
from app.line.step_fit import (
    MIN_STEP_REFS,
    StepCorrection,
    correct_step,
    locate_step,
    paired,
    reference_mm,
    step_sigma_mm,
    visible_step_mm,
    volume_views,
    with_references,
)
from calib.attribution import (
    NONE,
    SEVERAL,
    Attribution,
    maintenance_groups,
    point_shift_mm,
    step_groups,
)
from calib.candidates import IDEAL_STANDOFF_MM
from calib.uncertainty import sigma_upper_mm

#: the change point is looked for from the CUSUM's estimate less half the schedule (the
#: estimate can be late as well as early) up to the measurement that signalled
LOOK_BACK_DIVISOR = 2
REFINE_TRIES = 2  # refinements refused before the interval closes at the first correction


def suspect_open(svc: LineHost) -> bool:
    """A step's suspect interval is open."""
    if svc.step is None or svc.step.suspect_id is None:
        return False
    row = svc.store.suspect(svc.step.suspect_id)
    return row is not None and row["t_end"] is None


class StepHandler:
    """A flagged step's attribution, correction and suspect interval, on the service `svc`
    (whose decision state holds the step: `svc.step`)."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self._seen_window: int | None = None  # the window a waiting step was last looked at

    def open_step(self, onset_id: int, flag_id: int, *, attribute: bool) -> None:
        """A step was flagged at measurement `onset_id` (inside the transaction of the
        measurement). With `attribute` (every slot has a previous visit to compare with) it is
        on probation: the windows measure for its attribution, and `_confirm_step` opens its
        suspect interval and raises the high alarm once a group (or several) is chosen, while
        nothing found drops it as drift. Without, the suspect interval opens at once at the last
        trustworthy measurement before it, and it waits for the full recalibration."""
        svc = self.svc
        attribute = attribute and svc.settings.recalib.step_correction
        if svc.sequential is not None:
            if attribute:
                svc.sequential.hold(onset_id)  # widened once attributed
            else:
                svc.sequential.widen(onset_id)
        if svc.step is not None and svc.step.status in (
            StepStatus.PROBATION,
            StepStatus.ATTRIBUTING,
            StepStatus.PROPOSED,
        ):
            return  # the step in progress goes on
        status = StepStatus.PROBATION if attribute else StepStatus.SEVERAL
        text = f"step flagged at measurement {onset_id}"
        before = svc.store.measurements(before_id=onset_id, last=1)
        last_good = int(before[0]["id"]) if before else None
        t_start = float(
            before[0]["t"] if before else svc.store.measurements_by_id([onset_id])[0]["t"]
        )
        svc.step = Step(
            onset_id,
            None,
            t_start,
            last_good,
            status=status,
            text=text,
            flag_id=flag_id,
            change_from_before=svc.change_from_id,
            reference_mm=self._reference_level(),
        )
        svc.change_from_id = onset_id
        if not attribute:
            self.open_suspect(svc.step)

    def open_suspect(self, step: Step) -> None:
        """The step's suspect interval, from its last trustworthy measurement on. An accuracy
        interval open (the U95 jumped with the knock's first measurements, before the step was
        confirmed) becomes the step's: one interval for one event, starting at the step."""
        svc = self.svc
        fields = {
            "t_start": step.t_start,
            "last_good_id": step.last_good_id,
            "onset_id": step.onset_id,
            "params_version": svc.version,
            "text": step.text,
        }
        adopted = svc.accuracy_suspect_id
        if adopted is not None:
            row = svc.store.suspect(adopted)
            start = fields["t_start"] if row is None else min(fields["t_start"], row["t_start"])
            svc.store.update_suspect(adopted, **{**fields, "t_start": start, "group_name": None})
            svc.accuracy_suspect_id, step.suspect_id = None, adopted
        else:
            step.suspect_id = svc.store.open_suspect(fields)
        svc.bus.emit("suspect_interval", suspect_json(svc.store.suspect(step.suspect_id) or {}))

    def _sphere_alone(self, step: Step) -> str | None:
        """The `maintenance` alarm's text when one sphere moved beyond a knock on its own
        since the step's change point (app.line.beyond_knock.sphere_alone, on the residuals of
        the measurements since)."""
        svc = self.svc
        bound = svc.settings.recalib.maintenance_step_mm
        by: dict[str, list[float]] = {}
        for row in svc.store.measurements(status="ok", since_id=step.onset_id - 1):
            if row["residual_mm"] is not None:
                by.setdefault(str(row["target"]), []).append(float(row["residual_mm"]))
        name = sphere_alone(by, bound)
        return None if name is None else sphere_text(name, by, bound)

    def _hold_sphere_alone(self, step: Step, text: str) -> None:
        """One sphere moved beyond a knock on its own: no kinematic group explains it and no
        correction is applied; the step's interval says so and the cell holds for the
        fixture's procedure."""
        svc = self.svc
        with svc.store.batch():
            if step.status == StepStatus.PROBATION:
                self._confirm_step(step, text)
            step.choice, step.text = "fixture", text
            assert step.suspect_id is not None
            svc.store.update_suspect(step.suspect_id, group_name="fixture", text=text)
            step.move(StepStatus.MAINTENANCE)
            svc.save_state()
        svc.maintenance_needed(text)

    def _confirm_step(self, step: Step, text: str) -> None:
        """The attribution found a step: its suspect interval opens (from the last trustworthy
        measurement before where it was located) and the high alarm names what moved."""
        svc = self.svc
        step.move(StepStatus.ATTRIBUTING)
        self.open_suspect(step)
        svc.clear_alarms(AlarmCode.DRIFT)
        signal = step.signal or f"step since measurement {step.start_id or step.onset_id}"
        step.signal = signal
        svc.alarm(AlarmCode.DRIFT_STEP, step_alarm_text(signal, text), "high")

    def _drop_step(self, step: Step) -> None:
        """The attribution found no step on probation: it was drift (the recalibration is
        brought forward, on all recent measurements)."""
        svc = self.svc
        svc.step, svc.drift_onset_id, svc.drift_due = None, None, True
        # no step: a change since a visit before the flag is a change again (else a knock
        # right after a dropped flag goes unseen until every slot was visited again)
        svc.change_from_id = step.change_from_before
        if svc.sequential is not None:
            svc.sequential.widen(step.onset_id)

    def attribute_step(self) -> None:
        """Between windows, while a step is attributed: attribute it on the measurements from
        its change point on and, batch estimator, apply or propose the fast correction when
        its gates pass; sequential estimator, widen the suspected group's covariance."""
        svc = self.svc
        step, r = svc.step, svc.settings.recalib
        if step is None or not r.step_correction:
            return
        if step.status == StepStatus.REFINING:
            # the first correction's own measurements first: back, it ends there (no
            # refinement needed); else one window more of them refines it
            if not self.check_recovery():
                self._refine_step(step)
            return
        if step.status == StepStatus.RECOVERING:
            self.check_recovery()
            return
        waiting = (StepStatus.PROBATION, StepStatus.ATTRIBUTING, StepStatus.SEVERAL)
        window = svc.counters["windows"]
        if step.status not in waiting or window == self._seen_window:
            return  # (this runs between windows, every pass: once a window is enough)
        self._seen_window = window
        if step.status != StepStatus.PROBATION:
            self.check_vouched(step)
        if step.status not in (StepStatus.ATTRIBUTING, StepStatus.PROBATION):
            return
        alone = self._sphere_alone(step)
        if alone is not None:
            self._hold_sphere_alone(step, alone)
            return
        got = self._step_pairs(step, locate=True)
        if got is None:
            return
        n_all, start_id, after, sigma = got
        pairs = [p for p in after if p[1] is not None]
        views = self.volume_views()
        if len(pairs) < r.step_min_measurements:
            step.n_used = n_all
            return
        a, corr = correct_step(
            svc.model, svc.x, pairs, svc.spheres, sigma, views, r, svc.settings.gates
        )
        if corr is not None and not corr.passed and a.margin >= r.step_min_margin:
            a, corr = self._with_unreferenced(step, a, corr, after, sigma, views)
        if a.choice == SEVERAL and visible_step_mm(a) > r.maintenance_step_mm:
            # beyond a knock, no knock's group: maybe a maintenance's (J2's encoder zero)
            named, _ = correct_step(
                svc.model,
                svc.x,
                pairs,
                svc.spheres,
                sigma,
                views,
                r,
                svc.settings.gates,
                groups=maintenance_groups(svc.model),
            )
            if named.choice != SEVERAL:
                a, corr = named, None  # no correction beyond a knock
        step.n_used, step.choice, step.text = n_all, a.choice, a.text()
        settled = len(pairs) >= len(svc.schedule) // 2  # no single group after that many
        data = self._attribution_event(step, len(pairs), a, corr, views)
        size = data["size_mm"]
        decisive = a.margin >= r.step_min_margin
        with svc.store.batch():
            fields: dict[str, Any] = {"group_name": a.choice}
            start = self._step_start(step, start_id)
            if step.status == StepStatus.PROBATION or suspect_open(svc):
                # (an interval the cell vouched for keeps its span and its words)
                fields |= start | {"text": a.text()}
            seen = visible_step_mm(a)
            if step.status == StepStatus.PROBATION:
                data["visible_mm"] = seen
                # a visible step is confirmed when one group explains it decisively, or, once
                # no more measurements will tell (settled), undecided: its full recalibration
                # decides (measured: a new cell's J2 knock at a margin of 9-10 was dropped as
                # drift and left 0.23 mm off for 40 windows)
                confirmed = a.choice != NONE and (decisive or settled) and seen >= r.step_min_mm
                if not confirmed:
                    if (a.choice == NONE and decisive) or settled:  # drift, not a step
                        self._drop_step(step)
                    svc.save_state()  # else the next window measures for it again
                    svc.bus.emit("step_attribution", data, level=logging.WARNING)
                    return
                self._confirm_step(step, a.text())
            if size is not None:
                fields["size_mm"] = size
            assert step.suspect_id is not None
            svc.store.update_suspect(step.suspect_id, **fields)
            for alarm in svc.store.active_alarms(code=AlarmCode.DRIFT_STEP):
                text = step_alarm_text(step.signal, a.text())
                svc.store.update_alarm_message(int(alarm["id"]), text)
            closed, maintenance = None, beyond(a, seen, r.maintenance_step_mm)
            # beyond a knock: said once what moved is known (one group chosen decisively),
            # or when no more measurements will tell (settled, or the step's third window)
            maintenance &= (a.choice != SEVERAL and decisive) or settled or self._late(step)
            if maintenance:  # no correction: the cell holds for the procedure that fits
                step.move(StepStatus.MAINTENANCE)
            elif a.choice in (SEVERAL, NONE) and settled:
                step.move(a.choice)
                if a.choice == NONE:
                    closed = self.close_none(svc.clock.time())
            self._widen_sequential(a, step)
            svc.save_state()
        svc.bus.emit("step_attribution", data, level=logging.WARNING)
        if maintenance:
            svc.maintenance_needed(step_text(a, seen, r.maintenance_step_mm))
            return
        if closed is not None:
            svc.bus.emit("suspect_interval", closed)
        if svc.sequential is None and corr is not None and corr.passed:
            step.move(StepStatus.PROPOSED)
            step.base_version = svc.version
            step.level_sigma_mm = self._level_sigma(step)
            svc.recal_done(corr)

    def _late(self, step: Step) -> bool:
        """The step's measurements span BLIND_WINDOWS windows: no longer waited on."""
        rows = self.svc.store.measurements_by_id([step.onset_id])
        return bool(rows) and self.svc.counters["windows"] - int(rows[0]["window"]) + 1 >= (
            BLIND_WINDOWS
        )

    def _with_unreferenced(
        self,
        step: Step,
        a: Attribution,
        corr: StepCorrection,
        after: list[Any],
        sigma: float,
        views: tuple[Any, Any],
    ) -> tuple[Attribution, StepCorrection]:
        """A group chosen decisively on the pairs, whose correction failed its gates: the
        group fitted again on every measurement since the step, those without a reference (a
        new cell's slots not measured before it) on their own residuals, with the cell's
        level before the step for sigma (`step_fit.correct_step`). Taken when its gates pass
        (measured: a new cell's sensor knock waited 4 windows for its slots' second visits);
        else the pairs' attribution and correction as they were."""
        svc = self.svc
        level = self._level_sigma(step)
        if level is None or len(after) == corr.n_measurements + 1 or a.chosen is None:
            return a, corr
        groups = [g for g in step_groups(svc.model) if g.name in (NONE, a.choice)]
        a_all, corr_all = correct_step(
            svc.model,
            svc.x,
            after,
            svc.spheres,
            sigma,
            views,
            svc.settings.recalib,
            svc.settings.gates,
            groups=groups,
            absolute_sigma_mm=max(level, sigma),
        )
        if corr_all is None or not corr_all.passed:
            return a, corr
        return a_all, corr_all

    def _level_sigma(self, step: Step) -> float | None:
        """The upper bound of sigma [mm per coordinate] of the cell before the step: the
        evidence (app.line.accuracy.evidence: the version in force's held-out residuals
        topped up by its seed) of the schedule cycle before the step."""
        svc = self.svc
        n_max = len(svc.schedule)
        rows = svc.store.measurements(before_id=step.first_after_id, last=4 * n_max)
        norms, _ = evidence(rows, svc.version, None, svc.u_seed, n_max)
        s = sigma_upper_mm(norms)
        return None if math.isnan(s) else s

    def _step_pairs(self, step: Step, *, locate: bool) -> tuple[int, int, list[Any], float] | None:
        """(the measurements since before any candidate change point, their count: `n_used`;
        the located start; every measurement from it on with its freshest reference, None for
        one whose slot has none; sigma), or None when nothing new was measured or too few
        have references. `locate`: look for the change point (else the one located before
        stands)."""
        svc = self.svc
        r = svc.settings.recalib
        back = len(svc.schedule) // LOOK_BACK_DIVISOR
        lo = max(1, step.onset_id - back)
        prior = self._ids_before(step.onset_id)
        if len(prior) < len(svc.schedule):
            # a new cell's first schedule cycle: most slots were measured once, before the
            # step; a quarter of them looked back (the self-starting chart's change point is
            # close), the others the references (at least MIN_STEP_REFS)
            keep = max(min(MIN_STEP_REFS, len(prior)), len(prior) - len(prior) // 4)
            lo = prior[keep - 1] + 1 if keep else step.onset_id
        rows = svc.store.measurements(since_id=lo - 1)
        before = svc.store.measurements(before_id=lo, last=2 * len(svc.schedule))
        wide = paired(rows, before)  # references before any candidate change point
        if len(wide) < r.step_min_measurements or len(rows) == step.n_used:
            return None
        chart = svc.drift.change.charts.get("*")
        mu = chart.mu if chart is not None and chart.ready else None
        res = reference_mm(svc.model, svc.x, before, svc.spheres) if before else None
        sigma = step_sigma_mm(before, mu, r.seq_measurement_std_mm, res)
        if locate or step.start_id is None:
            i = locate_step(svc.model, svc.x, wide, svc.spheres, sigma, step.flag_id)
            start_id = int(wide[i][0]["id"])
        else:
            start_id = step.start_id
        # the rows after it, with the freshest references: the rows between lo and it, but not
        # those after the chart's change point with no pair (a new cell's start is located at
        # its first pair: the knock may have moved them; measured: one of them made a
        # reference, its pair showed no step, and a sensor knock stayed "several" 27 windows)
        after = [q for q in rows if int(q["id"]) >= start_id]
        judged = {int(p[0]["id"]) for p in wide}
        refs = before + [
            q
            for q in rows
            if int(q["id"]) < start_id and (int(q["id"]) < step.onset_id or int(q["id"]) in judged)
        ]
        return len(rows), start_id, with_references(after, refs), sigma

    def _interval_from(self, step: Step, start_id: int) -> int:
        """Where the suspect interval of a step located at `start_id` starts: in a new cell
        (fewer measurements before the step than slots) the earlier of it and the chart's
        change point, as the located start is a pair's and the measurements just after the
        knock may have none (a self-starting chart's change point is close; a learned CUSUM's
        can be far early, so a watched cell keeps the located one). The rows the step is
        fitted on and the post-step calibration's start at the located one (a change point 8
        measurements early mixed them into a correction that left 0.19 mm)."""
        new_cell = len(self._ids_before(step.onset_id)) < len(self.svc.schedule)
        return min(start_id, step.onset_id) if new_cell else start_id

    def _ids_before(self, onset_id: int) -> list[int]:
        """The ids of the good measurements before `onset_id`, a schedule cycle's at most
        (fewer: a new cell's first cycle)."""
        rows = self.svc.store.measurements(before_id=onset_id, last=len(self.svc.schedule))
        return [int(q["id"]) for q in rows]

    def _refine_step(self, step: Step) -> None:
        """The first correction is in force; once a window more was measured, its group is
        fitted again (from the parameters now in force) and applied when its gates pass (then
        tested for recovery, `corrected`). After two refusals, or when nothing is left to
        refine, the first correction is tested for recovery. The measurements of slots not
        measured before the step (a new cell's) count too, on their own residuals with the
        cell's level before the step for sigma (`step_fit.correct_step`): its few references
        alone would leave a poor first correction as it is (measured: 3 pairs left a sensor
        knock at 0.20 mm for 13 windows)."""
        svc = self.svc
        r = svc.settings.recalib
        level = step.level_sigma_mm
        got = self._step_pairs(step, locate=False)
        one_window = max(svc.settings.line.step_slots_per_window - 1, 1)
        if got is None or got[0] < step.n_corrected + one_window:
            return
        step.n_used, _, after, sigma = got
        pairs = after if level is not None else [p for p in after if p[1] is not None]
        groups = [g for g in step_groups(svc.model) if g.name in (NONE, step.choice)]
        views = self.volume_views()
        x_base = self._version_x(step.base_version)
        if x_base is None:  # its base is not readable: it ends where it was corrected
            self._end_refining()
            return
        a, corr = correct_step(
            svc.model,
            x_base,
            pairs,
            svc.spheres,
            sigma,
            views,
            r,
            svc.settings.gates,
            groups=groups,
            refine=True,
            x_in_force=svc.x,
            absolute_sigma_mm=None if level is None else max(level, sigma),
        )
        data = self._attribution_event(step, len(pairs), a, corr, views, refine=True)
        size = data["size_mm"]
        svc.bus.emit("step_attribution", data, level=logging.WARNING)
        if corr is not None and corr.passed:
            step.refine_mm = size
            svc.recal_done(corr)  # auto: applied at once, the interval closes
            return
        step.refine_tries += 1
        if corr is None or step.refine_tries >= REFINE_TRIES:
            self._end_refining()
        else:
            svc.save_state()

    def _attribution_event(
        self,
        step: Step,
        n: int,
        a: Attribution,
        corr: StepCorrection | None,
        views: tuple[Any, Any],
        *,
        refine: bool = False,
    ) -> dict[str, Any]:
        """The `step_attribution` event's data: the choice, its gates, and how far the
        correction moves points at the standoff from the parameters in force (`size_mm`; with
        no correction None, for a refinement 0: nothing moved)."""
        svc = self.svc
        size = 0.0 if refine else None
        if corr is not None and a.chosen is not None:
            c_std = np.tile([0.0, 0.0, IDEAL_STANDOFF_MM], (len(views[0]), 1))
            size = point_shift_mm(svc.model, svc.x, a.chosen.x, views[0], c_std)
        data: dict[str, Any] = {
            "onset_id": step.onset_id,
            "n": n,
            "choice": a.choice,
            "text": f"refinement: {a.text()}" if refine else a.text(),
            "passed": bool(corr is not None and corr.passed),
            "failures": [] if corr is None else list(corr.failures),
            "size_mm": size,
            "attribution": a.to_json(),
        }
        if refine:
            data["refine"] = True
        return data

    def _end_refining(self) -> None:
        """No refinement: the first correction is tested for recovery (`check_recovery`)."""
        svc = self.svc
        assert svc.step is not None
        svc.step.refine_mm = 0.0
        svc.step.move(StepStatus.RECOVERING)
        svc.save_state()
        self.check_recovery()

    def volume_views(self) -> tuple[Any, Any]:
        """The measuring volume's points at every configuration of the schedule (where a
        correction's uncertainty is predicted, app.line.step.volume_views)."""
        svc = self.svc
        q = np.array([s.q_deg for s in svc.schedule.slots])
        return volume_views(q, svc.settings.measuring_volume_mm)

    def _step_start(self, step: Step, start_id: int) -> dict[str, Any]:
        """The suspect interval's start for a step located at measurement `start_id`: the last
        good measurement before it (fields to update; none when unchanged)."""
        svc = self.svc
        if start_id == step.start_id:
            return {}
        # a change from before it spans it; the measurements after the step are from it on
        step.start_id = svc.change_from_id = svc.drift_onset_id = start_id
        before = svc.store.measurements(before_id=self._interval_from(step, start_id), last=1)
        if not before:
            return {}
        step.last_good_id, step.t_start = int(before[0]["id"]), float(before[0]["t"])
        return {"last_good_id": step.last_good_id, "t_start": step.t_start}

    def _widen_sequential(self, a: Attribution, step: Step) -> None:
        """The sequential estimator follows the step through its process noise: the suspected
        group's covariance widened once the choice is decisive (all of it for several groups,
        or when no group was found)."""
        svc = self.svc
        seq, r = svc.sequential, svc.settings.recalib
        if seq is None:
            return
        if step.status in (StepStatus.SEVERAL, StepStatus.NONE):
            seq.widen(step.onset_id)
        elif a.choice not in (SEVERAL, NONE) and a.margin >= r.step_min_margin:
            seq.widen_group(a.fit(a.choice).group.params)
            step.move(StepStatus.FOLLOWING)

    def corrected(
        self, t: float, version: int, cal: Mapping[str, Any] | None, kind: str
    ) -> dict[str, Any] | None:
        """A correction trained after the step (`kind`: a fast "step" correction, a "batch" or
        "sequential" calibration) went in force at `t` as `version`. The suspect interval
        stays open: the windows go on measuring for the step, and `check_recovery` closes it
        at this correction when the held-out residuals measured with it are back at their level
        before the step (a first fast correction, auto mode, batch estimator, is first refined
        once, `_refine_step`). Returns the closed interval's event data when it was already
        closed by nothing found (None otherwise)."""
        svc = self.svc
        step, r = svc.step, svc.settings.recalib
        if step is None or step.suspect_id is None:
            return None
        row = svc.store.suspect(step.suspect_id)
        if row is None or row["t_end"] is not None:
            return None
        if row["size_mm"] is None and row["params_version"] is not None:
            svc.store.update_suspect(
                step.suspect_id, size_mm=self._correction_size(int(row["params_version"]))
            )
        step.recover_version, step.recover_t, step.recover_kind = version, t, kind
        step.recover_n, step.recover_verdict, step.recover_look_n = 0, "", 0
        # a fast correction's predicted uncertainty (app.line.accuracy.with_prediction)
        est = ((cal or {}).get("document") or {}).get("estimator") or {}
        std = est.get("predicted_std_mm") if kind == "step" else None
        level = step.level_sigma_mm
        predicted = None if std is None or level is None else math.hypot(level, float(std))
        step.predicted_sigma_mm, step.predicted_version = predicted, version
        step.recover_cal_id = None if cal is None else int(cal["id"])
        last = svc.store.measurements(last=1)
        step.recover_from_id = int(last[0]["id"]) if last else 0
        if kind != "step":
            step.full_recals += 1
        refines = r.step_refine_mm > 0 and svc.applies_automatically() and svc.sequential is None
        busy = (StepStatus.REFINING, StepStatus.RECOVERING)
        if kind == "step" and step.status not in busy and refines:
            step.n_corrected = step.n_used
            step.move(StepStatus.REFINING)
        else:
            step.move(StepStatus.RECOVERING)
        return None

    def _level_rows(self, step: Step) -> list[float]:
        """The in-control level: the residuals [mm] (held out: each measured with parameters
        trained before it) of a schedule cycle of good measurements before the step's start."""
        svc = self.svc
        rows = svc.store.measurements(
            status="ok", before_id=step.first_after_id, last=len(svc.schedule)
        )
        return [float(q["residual_mm"]) for q in rows if q["residual_mm"] is not None]

    def _reference_level(self) -> float | None:
        """The level [mm] the recovery test compares with when no measurement before the step
        is at hand (`Step.reference_mm`, taken at the flag): the overall residual chart's, when
        it has its baseline (RMS of its residuals: sqrt(mu^2 + sigma^2); seeded, the
        calibration's residuals scaled to prediction errors, app.line.drift), else the
        calibration in force's training RMS scaled the same way (its document), else None."""
        svc = self.svc
        chart = svc.drift.residual.charts.get(OVERALL)
        if chart is not None and chart.ready and chart.mu > 0:
            return float(np.hypot(chart.mu, chart.sigma))
        seed = document_seed(svc.params.current_document())  # n norms of one size
        return seed[0] if seed else None

    def check_recovery(self) -> bool:
        """Between windows while recovering: the recovery test (app.line.step.recovery_test:
        an equivalence test, every look of the step sharing `recovery_confidence`) on the
        measurements taken with the correction under test in force, against the schedule cycle
        before the step (none: the step's `reference_mm`). Back: the suspect interval ends
        where that correction went in force. Not shown back, but the cell vouches for its U95
        within `accuracy_limit_mm` on the measurements after the step (app.line.accuracy): it
        ends there too ("vouched"; the relative test is information). Else it stays open and
        the windows go on measuring for the full recalibration on post-step measurements;
        after two full recalibrations since the step not shown back (higher, or undetermined
        on at least `recovery_min_measurements`) the cell has a new level and it closes saying
        so. While the first correction is refined, only "back" closes it. True when it
        closed."""
        svc = self.svc
        step, r = svc.step, svc.settings.recalib
        testing = (StepStatus.RECOVERING, StepStatus.REFINING)
        if step is None or step.status not in testing or step.recover_version is None:
            return False
        rows = [
            q
            for q in svc.store.measurements(status="ok", since_id=step.recover_from_id)
            if q["params_version"] == step.recover_version and q["residual_mm"] is not None
        ]
        if len(rows) == step.recover_n:
            return False  # nothing new measured
        step.recover_n = len(rows)
        test = recovery_under(
            r,
            self._level_rows(step),
            [float(q["residual_mm"]) for q in rows],
            looks=step.recover_looks,
            last_look_n=step.recover_look_n,
            reference_mm=step.reference_mm,
        )
        if test.look:
            step.recover_looks, step.recover_look_n = test.look, test.n_after
        step.recovery, step.recover_verdict = test.text, test.verdict
        svc.bus.emit(
            "recovery",
            {"onset_id": step.onset_id, "version": step.recover_version, **test.to_json()},
        )
        settled = (
            test.verdict != "back"
            and test.n_after >= r.recovery_min_measurements
            and step.full_recals >= 2
            and step.status == StepStatus.RECOVERING
        )
        # the plant's criterion: the cell vouches for its U95 (app.line.accuracy) with the
        # correction in force, on the measurements after the step, within accuracy_limit_mm
        acc = svc.accuracy
        vouched = (
            acc is not None
            and acc.vouched
            and (
                acc.basis == AFTER_STEP
                or (acc.basis == PREDICTED and test.n_after >= r.recovery_min_measurements)
            )
            and svc.version == step.recover_version
        )
        if test.verdict != "back" and not settled and not vouched:
            svc.save_state()
            return False
        if test.verdict == "back":
            reason = step.recover_kind or "step"
        else:
            reason = VOUCHED if vouched else "new level"
            if vouched and acc is not None:
                step.recovery = f"{step.recovery}; {acc.text()}"
        with svc.store.batch():
            closed = self._close(step, reason)
            svc.clear_alarms(AlarmCode.DRIFT_STEP)
            if step.recover_kind != "step":  # a full calibration after the step: it is over
                svc.drift_onset_id, svc.step = None, None
            svc.save_state()
        if closed is not None:
            svc.bus.emit("suspect_interval", closed)
        return True

    def check_vouched(self, step: Step) -> None:
        """A step with no correction in force (attributed, or several groups waiting for the
        full recalibration) whose interval is open: the interval ends when the cell vouches for
        its U95 within `accuracy_limit_mm` on at least `recovery_min_measurements` residuals
        measured after the step (app.line.accuracy, basis "after step"): a suspect interval is
        the time the cell cannot vouch (measured: 106 of the 221 windows suspect within the
        limit on seeds 25-28 had a U95 within it, a drift the charts flagged in the warm-up).
        Its bodies, measured since the step with the parameters in force, stay suspect in the
        windows whose U95 was above the limit when stated (`Store.vouched_since`: none, the
        interval ends where it began). The step goes on (its attribution, its full
        recalibration); the cell no longer vouching opens an accuracy interval."""
        svc = self.svc
        acc, r = svc.accuracy, svc.settings.recalib
        if acc is None or not acc.vouched or acc.basis != AFTER_STEP:
            return
        if acc.n < r.recovery_min_measurements or not suspect_open(svc):
            return
        # the bodies measured since the step with the same parameters: suspect only in the
        # windows the cell could not vouch for when they were stated
        t_end = svc.store.vouched_since(step.t_start, acc.limit_mm)
        if t_end is None:
            return
        assert step.suspect_id is not None
        text = f"{step.text or step.signal}; the cell vouches for its accuracy: {acc.text()}"
        with svc.store.batch():
            svc.store.update_suspect(
                step.suspect_id,
                t_end=t_end,
                end_reason=VOUCHED,
                end_version=svc.version,
                text=text,
            )
            svc.clear_alarms(AlarmCode.DRIFT_STEP)
            svc.save_state()
        svc.bus.emit("suspect_interval", suspect_json(svc.store.suspect(step.suspect_id) or {}))

    def _close(self, step: Step, reason: str) -> dict[str, Any] | None:
        """End the suspect interval where the correction under test went in force."""
        svc = self.svc
        assert step.suspect_id is not None
        fields: dict[str, Any] = {"t_end": step.recover_t, "end_reason": reason}
        if step.recover_version is not None:
            fields["end_version"] = step.recover_version
        if step.recover_cal_id is not None:
            fields["calibration_id"] = step.recover_cal_id
        if step.recovery:
            fields["text"] = f"{step.text}; {step.recovery}"
        svc.store.update_suspect(step.suspect_id, **fields)
        step.move(StepStatus.CORRECTED)
        return suspect_json(svc.store.suspect(step.suspect_id) or {})

    def close_none(self, t: float) -> dict[str, Any] | None:
        """No step was found: the interval ends now."""
        svc = self.svc
        step = svc.step
        if step is None or step.suspect_id is None or not suspect_open(svc):
            return None
        svc.store.update_suspect(step.suspect_id, t_end=t, end_reason="none")
        return suspect_json(svc.store.suspect(step.suspect_id) or {})

    def _version_x(self, version: int | None) -> Any:
        """The parameter vector of history version `version` (None when unreadable)."""
        svc = self.svc
        if version is None:
            return None
        try:
            return carried_from_json(svc.service_model, svc.params.version_path(version))[1]
        except (OSError, ValueError, KeyError, InputError):
            return None

    def _correction_size(self, old_version: int) -> float | None:
        """How far the parameters now in force move a point at the sensor's standoff from where
        version `old_version` put it, RMS over the schedule's views [mm]."""
        svc = self.svc
        x_old = self._version_x(old_version)
        if x_old is None:
            return None
        q = np.array([s.q_deg for s in svc.schedule.slots])
        c = np.tile([0.0, 0.0, IDEAL_STANDOFF_MM], (len(q), 1))
        return point_shift_mm(svc.model, x_old, svc.x, q, c)
