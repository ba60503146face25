"""The cell's state as one estimator on the service: `JumpWatch`, a collaborator of
app.line.service.Service that sees it as app.line.host.LineHost (docs/estimator.md).

The estimator (app.line.estimate: calib.cellstate's filter built from the version in force)
takes every good sphere measurement (`observe`, in the measurement's transaction) and tests
its window for a jump. Right after a window's measurements a jump found opens its *episode*
(`opened`); between windows (`act`) the service does what the test says:

- a jump detected: the suspect interval from the last measurement before the dated onset, the
  high `drift_step` alarm, the rolling set from the onset on;
- named to one group within a knock's bounds: its correction (the jump estimated with its
  covariance), checked (redundant, determined, predicting a measurement it was not fitted to)
  and gated (calib.gates change bounds), applied as a new version; beyond
  `[service] maintenance_step_mm`, or one sphere alone: the `maintenance` hold with the
  procedure that fits; no decisive group after `jump_settle` measurements: a full
  re-identification on the measurements since the onset, and the alarm says so;
- the episode's interval closes when `jump_confirm` measurements on the corrected version raise
  no jump and the cell vouches for its U95 again, dated when the correction came into force
  (its end reason the kind of the version: "step" for the jump's correction, "batch" for a
  recalibration); its group is watched a while after and refined from the estimator's
  posterior when still off.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.formats.params import document_covariance
from app.line.beyond_knock import (
    BLIND_WINDOWS,
    MaintenanceNeed,
    change_need,
    several_need,
    sphere_moved_need,
)
from app.line.correction import KIND, jump_correction, volume_views
from app.line.estimate import CellEstimate
from app.line.host import LineHost
from app.line.recalib import RecalOutcome
from app.line.states import AlarmCode, suspect_json
from calib.attribution import SEVERAL
from calib.cellstate import CellState
from calib.hypotheses import SPHERE, JumpFit, Verdict

#: equations after the onset beyond the jump's degrees of freedom before it is corrected (one
#: measurement's: the estimate is checked by data it was not determined by alone)
REDUNDANCY = 3
#: the p-value below which the episode's group, fitted again after its correction, is refined
REFINE_P = 0.01
REFINE_MAX = 2  # refinements of one episode
HALF_JUMP = 0.5  # a correction's predicted error (3-D) at most this share of the jump
HELD_OUT_P = 0.01  # the newest measurement's p-value under the jump fitted without it
REFINE_WATCH = 24  # measurements after its interval closed an episode's group is watched


class JumpWatch:
    """The estimator and its episodes on the service `svc` (module docstring)."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self.estimate = CellEstimate(svc)

    @property
    def state(self) -> CellState | None:
        return self.estimate.state

    @property
    def verdict(self) -> Verdict | None:
        return self.estimate.verdict

    def statement_u95_mm(self) -> float | None:
        """The U95 of a point measured now (app.line.estimate), with the innovations of a jump
        found and not corrected yet."""
        ep = self.episode
        onset = int(ep["onset_id"]) if ep is not None and self._uncorrected() else None
        return self.estimate.statement_u95_mm(onset)

    def point_cov_mm2(
        self, q_deg: NDArray[np.float64], c_sensor_mm: NDArray[np.float64], temp_c: float | None
    ) -> NDArray[np.float64] | None:
        """The shared error's covariance (3, 3) [mm^2] of a point measured now at this pose
        (calib.cellstate.CellState.point_cov_mm2: the parameters' offset and covariance through
        the model there, the unmodelled term; a body's value adds its own noise); None while a
        jump found is not corrected (the statement, with its innovations, speaks for the bodies
        then) or before any measurement of the version in force."""
        st = self.state
        if self._uncorrected() or st is None or not st.rows:
            return None
        return st.point_cov_mm2(q_deg, c_sensor_mm, temp_c)

    def _uncorrected(self) -> bool:
        """A jump found and not corrected yet."""
        ep = self.episode
        return ep is not None and ep.get("corrected_version") is None

    @property
    def episode(self) -> dict[str, Any] | None:
        """The jump in hand (the service's decision state, persisted: to_json)."""
        return self.svc.decision.episode

    @episode.setter
    def episode(self, value: dict[str, Any] | None) -> None:
        self.svc.decision.episode = value

    # -- what the service does -------------------------------------------------------------
    def opened(self) -> None:
        """Right after a window's measurements: a jump found in them opens its episode (its
        suspect interval, before the window's statement)."""
        v, ep = self.verdict, self.episode
        fresh = ep is None or ep.get("corrected_version") is not None or bool(ep.get("closed"))
        if v is not None and v.detected and v.best is not None and fresh:
            k, p = v.best.onset_ref, v.best.p_value
            pv = "p < 1e-12" if p < 1e-12 else f"p {p:.1g}"
            self._open_at(k, f"step of the cell since measurement {k} ({pv})")

    def act(self) -> None:
        """Between windows: an episode opened, corrected or closed as the verdict says."""
        v, ep = self.verdict, self.episode
        if v is None:
            return
        if v.detected and v.best is not None:
            if ep is not None and ep.get("closed"):
                self.episode = None  # a new jump: a new episode
            self.opened()
            self._isolate(v)
        elif ep is not None and ep.get("closed"):
            self._watch(ep)
        elif ep is not None and ep.get("corrected_version") == self.svc.version:
            self._confirm()
        self.estimate.verdict = None

    def _open_at(self, onset: int, text: str) -> None:
        """The episode of a change since measurement `onset`: its suspect interval (the open one
        of a correction that did not hold, or an accuracy interval adopted), the high
        `drift_step` alarm, the rolling set from the onset on."""
        svc = self.svc
        fields: dict[str, Any] = {"t_start": svc.clock.time(), "last_good_id": None}
        fields |= self._since(onset) | {"params_version": svc.version, "text": text}
        t_start = float(fields["t_start"])
        ep = self.episode
        with svc.store.batch():
            adopted = svc.accuracy.suspect_id
            if ep is not None and _interval_open(svc, ep):
                sid = int(ep["suspect_id"])  # the correction did not hold: the same interval
            elif adopted is not None and svc.store.suspect(adopted) is not None:
                # the cell could not vouch since before it was found: one interval for one
                # event, from the earlier of the two starts
                sid, svc.accuracy.suspect_id = adopted, None
                row = svc.store.suspect(sid) or {}
                start = min(t_start, float(row.get("t_start", t_start)))
                svc.store.update_suspect(sid, **{**fields, "t_start": start, "group_name": None})
            else:
                sid = svc.store.open_suspect(fields)
            self.episode = {
                "onset_id": onset,
                "suspect_id": sid,
                "group": "",
                "corrected_version": None,
                "window": svc.decision.counters["windows"],
                "clean": 0,
                "text": text,
            }
            svc.decision.jump_onset_id = onset  # the rolling set from the onset on
            svc.save_state()
        svc.bus.emit("suspect_interval", suspect_json(svc.store.suspect(sid) or {}))
        svc.alarm(AlarmCode.DRIFT_STEP, f"{text}: finding what moved", "high")

    def _isolate(self, v: Verdict) -> None:
        """What the verdict says moved: beyond a knock, the maintenance hold; a sphere alone,
        the same; one group, its correction once determined; none after `jump_settle`
        measurements, a full recalibration."""
        svc, ep, best = self.svc, self.episode, v.best
        assert ep is not None and best is not None and self.state is not None
        r = svc.settings.recalib
        if best.onset_ref < int(ep["onset_id"]):  # dated earlier with more measurements
            self._redate(ep, best.onset_ref)
        n_after = len(self.state.rows[best.onset :])  # the onset is in the window
        seen_mm = self._innovation_mm(best.onset)
        if seen_mm > r.maintenance_step_mm:
            self._beyond(ep, v, seen_mm)
            return
        h = best.hypothesis
        if v.isolated != SEVERAL and h.target is not None:
            self._sphere_moved(ep, best, seen_mm)
            return
        # the estimate checked by one measurement more than it needs, and the jump fitted
        # without the newest measurement predicting that one (p >= HELD_OUT_P)
        ready = v.isolated != SEVERAL and 3 * n_after - best.dof >= REDUNDANCY
        moved_mm = self._seen_mm(best)
        determined = ready and self._determined(best, moved_mm)
        if determined and self.state.held_out_p(h.name, best.onset) >= HELD_OUT_P:
            self._describe(ep, h.name, moved_mm, f"{h.label} {best.size_text()}")
            if svc.decision.pending_calibration is None and not svc.recalibrator.busy:
                svc.recal_done(self._correction(best, n_after))
            return
        if n_after >= r.jump_settle and not svc.decision.force_recal and ep["group"] != SEVERAL:
            svc.decision.force_recal = True
            guess = "no single group explains it" if v.isolated == SEVERAL else f"{h.label}?"
            self._describe(ep, SEVERAL, seen_mm, f"{guess}: a full recalibration")

    def _beyond(self, ep: dict[str, Any], v: Verdict, seen_mm: float) -> None:
        """A change beyond a knock: the maintenance hold, naming what moved when one group
        (the knocks' or J2's encoder zero) explains it decisively, else more than one thing."""
        svc, st, best = self.svc, self.state, v.best
        assert st is not None and best is not None
        bound = svc.settings.recalib.maintenance_step_mm
        fits = list(v.fits)
        fits += [f for h in st.beyond if (f := st.fit(h.name, best.onset)) is not None]
        fits.sort(key=lambda f: f.score, reverse=True)
        top = fits[0] if fits else None
        decisive = top is not None and (
            len(fits) == 1 or top.score - fits[1].score >= st.settings.margin
        )
        waited = svc.decision.counters["windows"] - int(ep["window"]) + 1 >= BLIND_WINDOWS
        if not (decisive or waited):  # more measurements name what moved; meanwhile the
            self._describe(ep, "", seen_mm, "beyond a knock: finding what moved")  # interval
            return
        if top is not None and decisive and top.hypothesis.target is not None:
            self._sphere_moved(ep, top, seen_mm)
            return
        if top is not None and decisive:
            h = top.hypothesis
            found = f"{h.label} moved {top.size_text()} ({seen_mm:.2f} mm at the measured spheres)"
            self._describe(ep, h.name, seen_mm, f"{h.label} {top.size_text()}")
            svc.maintenance_needed(
                change_need(h.name, h.label, found, top.size_text(), seen_mm, bound)
            )
            return
        self._describe(ep, SEVERAL, seen_mm, "more than one thing changed")
        svc.maintenance_needed(several_need(seen_mm, bound))

    def _sphere_moved(self, ep: dict[str, Any], fit: JumpFit, seen_mm: float) -> None:
        """One sphere moved alone (`fit`'s hypothesis names it): the maintenance hold."""
        h = fit.hypothesis
        self._describe(ep, h.name, seen_mm, f"{h.label} {fit.size_text()}")
        evidence = f"since measurement {fit.onset_ref}, the others where they were"
        moved = float(np.linalg.norm(fit.theta))
        bound = self.svc.settings.recalib.maintenance_step_mm
        self.svc.maintenance_needed(sphere_moved_need(str(h.target), moved, evidence, bound))

    def hold_blind(self, onset_id: int, need: MaintenanceNeed) -> None:
        """No view saw its sphere for BLIND_WINDOWS windows since measurement `onset_id`
        (app.line.window_loop): a change far beyond a knock, its episode's interval from there
        (an open one goes on), the cell held for the maintenance `need` says."""
        ep = self.episode
        if ep is None or ep.get("closed") or not _interval_open(self.svc, ep):
            self.episode = None
            self._open_at(onset_id, f"no sphere seen since measurement {onset_id}")
        ep = self.episode
        assert ep is not None
        self._describe(ep, "", None, "beyond a knock: no sphere where the parameters put it")
        self.svc.maintenance_needed(need)

    def _redate(self, ep: dict[str, Any], onset: int) -> None:
        """The episode's onset moved back to measurement `onset`: its interval from the last
        measurement before it, and the rolling set from it."""
        svc = self.svc
        fields = self._since(onset)
        with svc.store.batch():
            ep["onset_id"] = onset
            svc.decision.jump_onset_id = onset
            if _interval_open(svc, ep):
                svc.store.update_suspect(int(ep["suspect_id"]), **fields)
            svc.save_state()

    def _since(self, onset: int) -> dict[str, Any]:
        """An interval's start at a change since measurement `onset`: the last measurement
        before it, its time and id (none: the onset alone)."""
        before = self.svc.store.measurements(before_id=onset, last=1)
        if not before:
            return {"onset_id": onset}
        return {"onset_id": onset, "t_start": before[0]["t"], "last_good_id": before[0]["id"]}

    def _innovation_mm(self, onset: int) -> float:
        """The RMS innovation of the window's measurements from `onset` on [mm]: how far the
        measured centres moved from where the parameters in force put them."""
        assert self.state is not None
        rows = self.state.rows[onset:]
        d = self.state.d[: self.state.L]
        return _rms([float(np.linalg.norm(r.v0 - r.H @ d)) for r in rows])

    def _seen_mm(self, fit: JumpFit) -> float:
        """The jump's RMS move of the measured centres since its onset [mm]."""
        assert self.state is not None
        rows = self.state.rows[fit.onset :]
        if not rows:
            return 0.0
        moves = [r.G[fit.hypothesis.name] @ fit.theta for r in rows]
        return float(np.sqrt(np.mean([m @ m for m in moves])))

    def _describe(self, ep: dict[str, Any], group: str, seen_mm: float | None, what: str) -> None:
        """What moved, in the episode, its interval, its alarm and an event (`jump`)."""
        svc = self.svc
        if ep.get("group") == group and ep.get("what") == what:
            return
        ep["group"], ep["what"] = group, what
        fields: dict[str, Any] = {"group_name": group, "text": f"{ep['text']}: {what}"}
        if seen_mm is not None:
            fields["size_mm"] = seen_mm
        with svc.store.batch():
            svc.store.update_suspect(int(ep["suspect_id"]), **fields)
            for alarm in svc.store.active_alarms(code=AlarmCode.DRIFT_STEP):
                svc.store.update_alarm_message(int(alarm["id"]), f"{ep['text']}: {what}")
            svc.save_state()
        svc.bus.emit(
            "jump",
            {"group": group, "text": what, "onset_id": ep["onset_id"], "size_mm": seen_mm},
            level=logging.WARNING,
        )

    def _correction(self, fit: JumpFit, n_after: int) -> RecalOutcome:
        """The jump's group moved by its estimate, gated by the change bounds (the version in
        force's covariance and workspace validation carried: app.line.correction)."""
        svc, state = self.svc, self.state
        assert state is not None
        doc = svc.params.current_document()
        cov = None if doc is None else document_covariance(doc, svc.params.current_path)
        return jump_correction(
            svc.model, state, fit, n_after, svc.settings.gates, doc, cov, svc.version
        )

    def in_force(self, kind: str) -> None:
        """A version became current: the estimator restarts on it; a jump's correction (or a
        full recalibration during an episode) is now the episode's corrected version."""
        self.estimate.restart()
        ep = self.episode
        if ep is not None and self._uncorrected():
            ep["corrected_version"] = self.svc.version
            ep["corrected_t"] = self.svc.clock.time()
            ep["kind"] = kind  # the interval's end reason: "step" (the jump's) or "batch"
            ep["clean"] = 0

    def _confirm(self) -> None:
        """A measurement on the corrected version with no jump. The episode's group, fitted
        again on the measurements since the correction, still moved (p < REFINE_P: a test of
        the one group named before): its refinement is applied (at most REFINE_MAX). Else after
        `jump_confirm` of them, and the cell vouching, the episode is over."""
        svc, ep = self.svc, self.episode
        assert ep is not None
        if self._refine(ep):
            return
        ep["clean"] = int(ep.get("clean", 0)) + 1
        u95 = self.statement_u95_mm()
        if ep["clean"] < svc.settings.recalib.jump_confirm or not (
            u95 is not None and u95 <= svc.settings.recalib.accuracy_limit_mm
        ):
            svc.save_state()
            return
        # the parameters were wrong until the correction came into force: its confirmation
        # dates the interval's end there (the bodies measured since were measured right)
        t = svc.clock.time()
        t_end = float(ep.get("corrected_t", t))
        st = self.state
        held_out = [] if st is None else [float(np.linalg.norm(r.v0)) for r in st.rows]
        evidence = (
            f"; back on version {svc.version}: {len(held_out)} measurement(s) since, no jump,"
            f" held-out RMS {_rms(held_out):.3f} mm, U95 {u95:.3f} mm <= limit"
            f" {svc.settings.recalib.accuracy_limit_mm:.3f} mm"
        )
        with svc.store.batch():
            sid = int(ep["suspect_id"])
            if _interval_open(svc, ep):
                text = str((svc.store.suspect(sid) or {}).get("text", ""))
                svc.store.update_suspect(
                    sid,
                    t_end=t_end,
                    end_reason=str(ep.get("kind", KIND)),
                    end_version=svc.version,
                    text=text + evidence,
                )
            # its group watched a while for a refinement (the rolling set stays after the
            # onset until a recalibration trained there is in force: app.line.versions)
            ep |= {"closed": True, "watch_left": REFINE_WATCH}
            svc.clear_alarms(AlarmCode.DRIFT_STEP, t)
            svc.save_state()
        svc.bus.emit("suspect_interval", suspect_json(svc.store.suspect(sid) or {}))

    def _refine(self, ep: dict[str, Any]) -> bool:
        """The episode's group as the estimator sees it on the corrected version (its
        posterior, every measurement since the correction): still off (p < REFINE_P, a test of
        the one group named before) and determined, its refinement is applied; whether it
        was."""
        svc, st = self.svc, self.state
        group = str(ep.get("group", ""))
        if st is None or not group or group == SEVERAL or group.startswith(SPHERE):
            return False
        if int(ep.get("refined", 0)) >= REFINE_MAX or svc.decision.pending_calibration is not None:
            return False
        fit = st.group_posterior(group)
        if fit is None or fit.p_value >= REFINE_P or 3 * len(st.rows) - fit.dof < REDUNDANCY:
            return False
        if not self._determined(fit, self._seen_mm(fit)):
            return False
        ep["refined"] = int(ep.get("refined", 0)) + 1
        if not ep.get("closed"):
            ep["corrected_version"] = None  # the refinement's version becomes it
        svc.recal_done(self._correction(fit, len(st.rows)))
        return True

    def _watch(self, ep: dict[str, Any]) -> None:
        """An episode whose interval closed: its group watched for a refinement for
        REFINE_WATCH measurements more, then the episode is over."""
        if self._refine(ep):
            return
        ep["watch_left"] = int(ep.get("watch_left", REFINE_WATCH)) - 1
        if ep["watch_left"] <= 0:
            self.episode = None
        self.svc.save_state()

    def _determined(self, fit: JumpFit, seen_mm: float) -> bool:
        """The jump's estimate predicts the points in the measuring volume at the schedule's
        configurations within `[service] step_max_std_mm`, or, beside a large jump, within
        HALF_JUMP of it: the correction leaves at most half the error it removes (the rest is
        refined as measurements come, `_refine`)."""
        assert self.state is not None
        r = self.svc.settings.recalib
        q, c = volume_views(
            np.array([s.q_deg for s in self.svc.schedule.slots]),
            self.svc.settings.measuring_volume_mm,
        )
        std_mm = self.state.predicted_std_mm(fit, q, c)
        return std_mm <= max(r.step_max_std_mm, HALF_JUMP * seen_mm / math.sqrt(3.0))

    def interval_open(self) -> bool:
        """An episode's suspect interval is open."""
        return _interval_open(self.svc, self.episode)

    def handling(self) -> bool:
        """An episode is open and not given up to a full recalibration."""
        ep = self.episode
        return ep is not None and not ep.get("closed") and ep.get("group") != SEVERAL

    # -- the decision state ------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """The episode and the evidence about s_u carried into the version in force (its own
        comes again from replaying its measurements at a start)."""
        ep = self.episode
        return {"episode": ep and dict(ep), "carried_moments": self.estimate.to_json()}

    def load_json(self, doc: dict[str, Any] | None) -> None:
        ep = (doc or {}).get("episode")
        self.episode = None if ep is None else dict(ep)
        self.estimate.load_json((doc or {}).get("carried_moments"))


def _interval_open(svc: LineHost, ep: dict[str, Any] | None) -> bool:
    if ep is None or ep.get("suspect_id") is None:
        return False
    row = svc.store.suspect(int(ep["suspect_id"]))
    return row is not None and row["t_end"] is None


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


__all__ = ["SPHERE", "JumpWatch"]
