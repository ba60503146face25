"""The sequential estimator (calib.sequential) as the service's recalibration, `[service]
estimator = "sequential"`, beside the batch identification on a rolling set (app.line.recalib).

Every good measurement is offered in id order. It is fed to the estimator (an extended Kalman
update with a random-walk drift per update and a chi-square gate) only once `holdout_size` newer
measurements exist, so the most recent ones stay held out: each `seq_apply_every` accepted
updates the estimate is a candidate, gated like a batch one (finite; change from the parameters
in force within the in-line bounds; held-out RMS <= max_holdout_ratio x that of the parameters in
force) and, when it passes, applied (auto) or left for approval, exactly as a batch candidate.

A jump the one estimator finds (app.line.jumps) is corrected as a version of its own; the
filter restarts from every version it did not make.
When
parameters are applied by another route (the initial ones, a rollback) the estimator restarts
from them, with the covariance of their identification when the document has one.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
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
    ) -> None:
        self.settings, self.gates, self.spheres = settings, gates, spheres
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

    def _drain(self) -> None:
        while len(self.queue) > self.settings.holdout_size:
            self._feed(self.queue.popleft())

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
        """A candidate can be made now (an operator's "calibrate now"): the filter runs and
        has held-out rows to gate it on."""
        return self.est is not None and self.first_id is not None and bool(self.queue)

    def due(self) -> bool:
        """A candidate is due: `seq_apply_every` accepted updates since the last one."""
        if self.est is None or not self.queue:
            return False
        return self.accepted_since >= self.settings.seq_apply_every

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
        return out
