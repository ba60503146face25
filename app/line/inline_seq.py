"""The sequential estimator (calib.sequential) as the service's recalibration, `[service]
estimator = "sequential"`, beside the batch identification on a rolling set (app.line.recalib).

Every good measurement is offered in id order. It is fed to the estimator (an extended Kalman
update with a random-walk drift per update and a chi-square gate) only once `holdout_size` newer
measurements exist, so the most recent ones stay held out: each `seq_apply_every` accepted
updates the estimate is a candidate, gated like a batch one (finite; change from the parameters
in force within the in-line bounds; held-out RMS <= max_holdout_ratio x that of the parameters in
force) and, when it passes, applied (auto) or left for approval, exactly as a batch candidate.

A step flagged by the drift charts (a knock) widens the covariance at once (`widen`), before
the post-step measurements reach the estimator (they are held out first; the held-out ones from
before the step are dropped), so that the estimate follows the new cell instead of rejecting it
until `knock_after` rejections in a row. The next candidate then waits for a full schedule cycle
of updates after the step and for the estimate's own covariance to predict the schedule's views
to `seq_max_std_mm` per coordinate. Both are needed. A few configurations cannot pin 30 widened
parameters: measured, 8 updates after a 0.3 mm knock gave a candidate that passed the held-out
gate and was 0.37 mm off at the validation positions (its predicted uncertainty near 1 mm). The
covariance alone is optimistic: it knows the sensor noise, not what the model leaves out (the
rigid model's gravity compliance); measured, a candidate whose predicted uncertainty was 0.019
mm after about 20 post-step updates was 0.065 mm off, the next ones 0.054 and 0.046. When
parameters are applied by another route (the initial ones, a rollback) the estimator restarts
from them, with the covariance of their identification when the document has one.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.config.line import RecalibSettings
from app.formats.params import parameters_json, plain_document
from app.line.recalib import as_measurements, rms_mm
from app.line.schedule import Slot
from calib.gate_limits import Gates
from calib.gates import change_failures
from calib.model import SystemModel
from calib.sequential import SequentialEstimator, SequentialSettings

F64 = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class SequentialCandidate:
    """An estimate to gate and apply: the same fields the service stores for a batch one."""

    passed: bool
    failures: tuple[str, ...]
    document: dict[str, Any]
    rms_mm: float  # of the innovations accepted since the last candidate
    holdout_rms_mm: float
    current_holdout_rms_mm: float
    n_measurements: int
    first_id: int
    last_id: int


def covariance_from(doc: Mapping[str, Any] | None, model: SystemModel) -> tuple[list[str], F64]:
    """(active names, covariance) of a parameters document's identification, or ([], empty)
    when it carries none (a plain document) or does not match the model."""
    if not doc or "correlation" not in doc or "active" not in doc:
        return [], np.zeros((0, 0))
    by_name = {str(p["name"]): p for p in doc.get("parameters", [])}
    names = [str(n) for n in doc["active"]]  # the order of the correlation matrix
    if not set(names) <= set(by_name):
        return [], np.zeros((0, 0))
    std = np.array([float(by_name[n]["std"]) for n in names])
    corr = np.asarray(doc["correlation"], dtype=float)
    if corr.shape != (len(names), len(names)) or not set(names) <= set(model.names):
        return [], np.zeros((0, 0))
    if not (np.all(np.isfinite(std)) and np.all(std > 0)):
        return [], np.zeros((0, 0))
    return names, corr * np.outer(std, std)


class InlineSequential:
    """Feeds the estimator with held-out lag, proposes gated candidates (module docstring)."""

    def __init__(
        self,
        settings: RecalibSettings,
        gates: Gates,
        spheres: Mapping[str, F64],
        n_slots: int,
    ) -> None:
        """`n_slots`: the schedule's length."""
        self.settings, self.gates, self.spheres = settings, gates, spheres
        self.n_slots = n_slots
        self.after_step = False
        self.holding = False  # a step flagged, not attributed yet: post-step rows wait
        self.group_step = False  # the suspected group widened: candidates without waiting
        self.queue: deque[Mapping[str, Any]] = deque()
        self.est: SequentialEstimator | None = None
        self.accepted_since = 0
        self.innovations: list[float] = []
        self.first_id: int | None = None

    def _seq_settings(self) -> SequentialSettings:
        s = self.settings
        return SequentialSettings(
            measurement_std_mm=s.seq_measurement_std_mm,
            drift_mm=s.seq_drift_mm,
            drift_rad=s.seq_drift_rad,
            drift_extra=s.seq_drift_extra,
            knock_mm=s.seq_knock_mm,
            knock_rad=s.seq_knock_rad,
        )

    def restart(self, model: SystemModel, x: F64, doc: Mapping[str, Any] | None) -> None:
        """Parameters `x` are in force: estimate from them on."""
        names, cov = covariance_from(doc, model)
        s = self.settings
        if names:
            self.est = SequentialEstimator(model, x, names, cov, self._seq_settings())
        else:
            self.est = SequentialEstimator.from_prior(
                model,
                x,
                model.default_active(),
                std_mm=s.seq_prior_mm,
                std_rad=s.seq_prior_rad,
                settings=self._seq_settings(),
            )
        self.accepted_since, self.innovations, self.first_id = 0, [], None

    def widen(self, onset_id: int) -> None:
        """A step was flagged at measurement `onset_id`: the parameters may have jumped. The
        held-out rows before it are dropped (stale), the covariance widened, and the next
        candidate waits until the estimate predicts the schedule's views well again."""
        if self.est is None:
            return
        self.queue = deque(r for r in self.queue if int(r["id"]) >= onset_id)
        self.est.widen()
        self.accepted_since, self.innovations, self.first_id = 0, [], None
        self.after_step, self.holding, self.group_step = True, False, False
        self._drain()

    def hold(self, onset_id: int) -> None:
        """A step was flagged at measurement `onset_id`, what moved is not known yet: the
        held-out rows before it are dropped (stale) and the rows after it wait in the queue
        (fed to a filter that has not been widened, the gate would reject them) until
        `widen_group` or `widen`."""
        self.queue = deque(r for r in self.queue if int(r["id"]) >= onset_id)
        self.holding = True

    def widen_group(self, names: Sequence[str]) -> None:
        """The step was attributed to one group (app.line.step): only its covariance grows
        (the process noise of a knock, `seq_knock_mm` / `seq_knock_rad`), the rows after the
        step are fed at once, all but the newest (held out), and a candidate is due as soon
        as the estimate predicts the schedule's views within `seq_max_std_mm`: no full
        schedule cycle is waited for, the other parameters are as well known as before."""
        if self.est is None:
            return
        self.est.widen(names)
        self.accepted_since, self.innovations, self.first_id = 0, [], None
        self.holding, self.group_step, self.after_step = False, True, True
        self._drain()

    def _holdout(self) -> int:
        return 1 if self.group_step else self.settings.holdout_size

    def _drain(self) -> None:
        while not self.holding and len(self.queue) > self._holdout():
            self._feed(self.queue.popleft())

    def step_json(self) -> dict[str, bool]:
        """The step flags (the service's decision state)."""
        return {"after_step": self.after_step, "holding": self.holding, "group": self.group_step}

    def load_step_json(self, doc: Mapping[str, Any] | None) -> None:
        doc = doc or {}
        self.after_step = bool(doc.get("after_step", False))
        self.holding = bool(doc.get("holding", False))
        self.group_step = bool(doc.get("group", False))

    def offer(self, row: Mapping[str, Any]) -> None:
        """A good measurement row (as stored); the oldest beyond the hold-out is fed."""
        self.queue.append(row)
        self._drain()

    def _feed(self, row: Mapping[str, Any]) -> None:
        assert self.est is not None, "restart() first"
        target = self.spheres[row["target"]]
        up = self.est.update(row["q_deg"], row["c_sensor_mm"], target, row.get("temp_c"))
        if up.accepted:
            self.accepted_since += 1
            self.innovations.append(float(np.linalg.norm(up.innovation_mm)))
            if self.first_id is None:
                self.first_id = int(row["id"])

    def most_informative(
        self, model: SystemModel, slots: Sequence[Slot], seen: Mapping[int, tuple[F64, F64]]
    ) -> Slot:
        """Adaptive scheduling: of these slots (they fit the window), the one whose measurement
        brings the most information given the current covariance (calib.sequential
        information_gain). The sphere's centre in the sensor frame is the slot's last measured
        one, or the model's prediction for a slot not measured yet."""
        assert self.est is not None, "restart() first"
        x = self.est.x
        c = []
        for slot in slots:
            if slot.index in seen:
                c.append(seen[slot.index][1])
            else:
                T = model.fk(x, slot.q_deg.reshape(1, 6))[0]
                p = np.append(self.spheres[slot.target], 1.0)
                c.append((np.linalg.inv(T) @ p)[:3])
        q = np.array([s.q_deg for s in slots])
        return slots[self.est.choose_next(q, np.array(c))]

    def can_propose(self) -> bool:
        """A candidate can be made now (an operator's "calibrate now"): the filter runs, has
        held-out rows to gate it on and is not holding rows for a step being attributed."""
        return (
            self.est is not None
            and self.first_id is not None
            and bool(self.queue)
            and (not self.holding)
        )

    def due(self, views: Callable[[], tuple[F64, F64]]) -> bool:
        """A candidate is due: `seq_apply_every` accepted updates since the last one; after a
        step, a full schedule cycle of them and the estimate's predicted point uncertainty at
        the schedule's views, `views()` -> (K, 6) joints with their last measured centres
        (K, 3) (asked only then), at most `seq_max_std_mm` per coordinate."""
        if self.est is None or not self.queue or self.holding:
            return False
        if self.group_step:
            if self.accepted_since < 1:
                return False
        elif self.accepted_since < self.settings.seq_apply_every:
            return False
        if not self.after_step:
            return True
        if not self.group_step and self.accepted_since < self.n_slots:
            return False
        q, c = views()
        return len(q) > 0 and self.est.predicted_std_mm(q, c) <= self.settings.seq_max_std_mm

    def candidate(self, model: SystemModel, x_current: F64) -> SequentialCandidate:
        """The estimate now, gated against the parameters in force on the held-out rows."""
        assert self.est is not None and self.first_id is not None and self.queue
        x = self.est.x
        holdout = as_measurements(list(self.queue), self.spheres)
        cand, cur = rms_mm(model, x, holdout), rms_mm(model, x_current, holdout)
        failures = [] if np.all(np.isfinite(x)) else ["non-finite parameters"]
        failures += change_failures(self.est.active, x, x_current, self.gates)
        ratio = self.gates.max_holdout_ratio
        if ratio is not None and not cand <= ratio * cur:
            failures.append(
                f"held-out RMS {cand:.4f} mm not better than the parameters in force ({cur:.4f} mm)"
            )
        doc = plain_document(model, x, "rvis run (sequential estimator)")
        std = dict(zip(self.est.active, self.est.std.tolist(), strict=True))
        doc["parameters"] = parameters_json(model, x, std)
        sd = np.sqrt(np.diag(self.est.covariance))
        doc["active"] = list(self.est.active)
        doc["correlation"] = (self.est.covariance / np.outer(sd, sd)).round(6).tolist()
        doc["success"] = not failures
        doc["estimator"] = {
            "kind": "sequential",
            "accepted": self.est.n_accepted,
            "rejected": self.est.n_rejected,
            "knocks": self.est.n_knocks,
        }
        rms = float(np.sqrt(np.mean(np.square(self.innovations))))
        out = SequentialCandidate(
            not failures,
            tuple(failures),
            doc,
            rms,
            cand,
            cur,
            self.accepted_since,
            self.first_id,
            int(self.queue[-1]["id"]),
        )
        self.accepted_since, self.innovations, self.first_id = 0, [], None
        if out.passed:
            self.after_step = self.group_step = False
        return out
