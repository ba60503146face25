"""The one estimator on the service: `CellEstimate`, calib.cellstate's filter and jump test
built from the version in force and fed the service's measurements (app.line.jumps decides what
the service does with its verdicts).

- **Prior**: the version in force's covariance (a parameter it has none for: the nominal's
  tolerances, `[service] seq_prior_mm` and `seq_prior_rad`); a new cell's is its
  commissioning's.
- **A measurement's own noise**: `sphere_sigma_mm`, the sensor's and the robot's repeatability
  through the model at the schedule's views (or `[service] jump_sigma_mm` when set), resolved
  once at the service's start; what the statement holds apart from its other terms, and what a
  body's value takes out of it (app.inspect.values).
- **Unmodelled term's floor**: from the commissioning's workspace validation (`_floors`): its
  mean square in the filter and the jump test, its upper 95 % bound in the statement.
- **Restart**: on every version in force, the measurements since it is in force replayed, the
  evidence about the unmodelled term carried from the version before (and across a restart of
  the service: `to_json`).
- **Statement**: the U95 of a point measured now with the parameters in force, at the window's
  poses: k (2.80, the 95 % quantile of a 3-D error's norm) times the per-coordinate
  sqrt((|H d|^2 + tr(H P H')) / 3 + s_u^2 + sigma^2), s_u at least the floor's bound, d and P
  the estimator's posterior of how
  far the parameters in force are off, and, while a jump is not corrected, its innovations;
  before the version's first measurement, d = 0 and P its prior at the schedule's views.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.formats.params import document_covariance
from app.line.host import LineHost
from app.line.recalib import Posterior
from app.line.schedule import Schedule
from app.line.settings import ServiceSettings
from calib.cellstate import CellState, EstimatorSettings, Observation
from calib.hypotheses import Verdict
from calib.model import EXTRA_NAMES, INDEX, SystemModel, unit_of
from calib.repeatability import stop_sd_mm
from calib.uncertainty import norm_quantile, sigma_upper_mm

#: the least noise a sphere measurement is given [mm] (an exact robot and sensor: the filter
#: needs some)
MIN_SIGMA_MM = 0.001


def sphere_sigma_mm(
    settings: ServiceSettings,
    model: SystemModel,
    x: NDArray[np.float64],
    schedule: Schedule,
    spheres: Mapping[str, NDArray[np.float64]],
) -> float:
    """One coordinate of a sphere measurement's own noise [mm]: `[service] jump_sigma_mm` when
    set (> 0); else the root sum of squares of the sensor's own ([sensor] centre_sd_mm) and the
    robot's repeatability at a stop, the data sheet's RP ([robot] repeatability_mm) through the
    model at the schedule's views (calib.repeatability.stop_sd_mm); at least MIN_SIGMA_MM."""
    if settings.recalib.jump_sigma_mm > 0.0:
        return float(settings.recalib.jump_sigma_mm)
    q, p = schedule.views(spheres)
    robot = stop_sd_mm(model, x, q, p, settings.repeatability_mm)
    return max(math.hypot(robot, settings.sensor_centre_sd_mm), MIN_SIGMA_MM)


class CellEstimate:
    """The estimator of the service `svc` (module docstring): `state` (None before the first
    start), the last measurement's `verdict` (None once acted on)."""

    def __init__(self, svc: LineHost) -> None:
        self.svc = svc
        self.state: CellState | None = None
        self.verdict: Verdict | None = None
        self._moments: list[float] = []  # s_u's evidence, carried from version to version
        self._stated_floor_mm2 = 0.0  # the statement's floor of s_u^2 (`_floors`)
        # per sphere, its measurements in the window (`summarise`), as of the last window or
        # start: replaced whole, read by any thread
        self.sphere_summary: dict[str, dict[str, Any]] = {}

    def settings(self, unmodelled_mm: float) -> EstimatorSettings:
        r = self.svc.settings.recalib
        return EstimatorSettings(
            sigma_mm=r.jump_sigma_mm,
            unmodelled_mm=unmodelled_mm,
            drift_mm_per_h=r.jump_drift_mm_per_h,
            drift_rad_per_h=r.jump_drift_rad_per_h,
            window=r.jump_window,
            false_alarm=r.jump_false_alarm,
        )

    def _floors(self) -> tuple[float, float]:
        """The unmodelled term's floor, from the commissioning's workspace validation: one
        coordinate's variance of its errors (their mean square, and its upper one-sided 95 %
        bound, calib.uncertainty.sigma_upper_mm, the bound the commissioning
        states its U95 from), less the measurement's own noise, which the statement holds apart.
        For the version it validated, all of it (its covariance at the spheres' views does not
        hold the error across the workspace); for a later version, less what the
        recalibrations since removed: the validated version's parameter variance at the
        schedule's views less the version in force's (a posterior from a few more measurements
        states what the validated version did). Without a validation, `[service]
        jump_unmodelled_mm`. The filter and the jump test take the mean square (the best
        estimate: a bound there slowed the detection of a J3 slip by a window), the statement
        the bound (20 positions know the mean square to about +-18 %: a statement from it
        covered fewer than 95 % of the points in 11 of 144 runs; from the bound, in none). Both
        as one coordinate's sigma [mm]: (the mean square's, the bound's)."""
        svc = self.svc
        sigma = svc.settings.recalib.jump_sigma_mm
        current = svc.params.current_document()

        def variance(doc: dict[str, Any] | None) -> float:  # 0: no covariance
            got = None if doc is None else document_covariance(doc, svc.params.current_path)
            return 0.0 if got is None else self._variance_at_schedule(*got)

        for doc in (current, svc.params.document(1)):
            errors = ((doc or {}).get("validation") or {}).get("errors_mm")
            if not errors or doc is None:
                continue
            norms = [float(e) for e in errors]
            less = sigma**2
            if doc is not current:
                less += max(0.0, variance(doc) - variance(current))
            mean_sq = float(np.mean(np.square(norms))) / 3.0
            bound_sq = sigma_upper_mm(norms) ** 2
            return math.sqrt(max(0.0, mean_sq - less)), math.sqrt(max(0.0, bound_sq - less))
        given = float(svc.settings.recalib.jump_unmodelled_mm)
        return given, given

    def _variance_at_schedule(self, names: list[str], cov: np.ndarray) -> float:
        """One coordinate's variance [mm^2] of a sphere's centre from parameters `names` with
        covariance `cov`, the mean over the schedule's views: trace(H cov H') / 3."""
        svc = self.svc
        keep = [k for k, n in enumerate(names) if n in INDEX]
        q, p = svc.schedule.views(svc.spheres)
        if not keep or not len(q):
            return 0.0
        c = svc.model.points_sensor(svc.x, q, p)
        H = svc.model.point_jacobian(svc.x, q, c, [names[k] for k in keep])
        C = cov[np.ix_(keep, keep)]
        return float(np.mean(np.einsum("kil,lm,kim->k", H, C, H)) / 3.0)

    def restart(self) -> None:
        """The estimator from the version in force, the measurements since it is in force
        replayed (a restarted service resumes where it stopped)."""
        svc = self.svc
        if self.state is not None:
            self._moments = self.state.moments()
        active = svc.model.default_active()
        P0 = self._prior(active)
        # every measurement since the version is in force (its posterior is a recalibration's
        # candidate: app.line.recalib), from the first one's time (the drift's clock), as the
        # service that never stopped has them
        mine = svc.store.measurements_of_version(svc.version)
        floor, stated = self._floors()
        self.state = CellState(
            svc.model, svc.x, active, P0, list(svc.spheres), self.settings(floor)
        )
        self._stated_floor_mm2 = stated**2
        self.state.learned(self._moments)
        self.verdict = None
        for r in mine:
            self.verdict = self.state.add(self._observation(r), test=r is mine[-1])
        self.summarise()

    def _prior(self, active: tuple[str, ...]) -> np.ndarray:
        """The covariance of the version in force on `active` (a parameter it has none for: the
        prior of `[service] seq_prior_mm` and `seq_prior_rad`, the nominal's tolerances; the
        extra terms tight)."""
        svc, r = self.svc, self.svc.settings.recalib
        mm2, rad2 = r.seq_prior_mm**2, r.seq_prior_rad**2
        var = [1e-12 if n in EXTRA_NAMES else mm2 if unit_of(n) == "mm" else rad2 for n in active]
        P = np.diag(var)
        doc = svc.params.current_document()
        got = None if doc is None else document_covariance(doc, svc.params.current_path)
        if got is not None:
            names, C = got
            ia = [k for k, n in enumerate(active) if n in names]
            ic = [names.index(active[k]) for k in ia]
            P[np.ix_(ia, ia)] = C[np.ix_(ic, ic)]
        return P

    def _observation(self, row: dict[str, Any]) -> Observation:
        target, temp = str(row["target"]), row.get("temp_c")
        q, c = (np.asarray(row[k], float) for k in ("q_deg", "c_sensor_mm"))
        p = self.svc.spheres[target]
        t_c = None if temp is None else float(temp)
        return Observation(int(row["id"]), float(row["t"]), target, p, q, c, t_c)

    def observe(self, row: dict[str, Any]) -> None:
        """A good measurement (its stored row with its id) into the estimator, tested."""
        if self.state is None:
            self.restart()
            return
        self.verdict = self.state.add(self._observation(row))

    def posterior(self) -> Posterior | None:
        """The parameters' posterior as a recalibration's candidate (app.line.recalib.RecalJob)
        with `[service] candidate = "posterior"`, while the version in force is its prior: no
        jump in hand (after one, the measurements since its onset are identified alone) and a
        measurement of the version in the estimator."""
        st = self.state
        if self.svc.settings.recalib.candidate != "posterior":
            return None
        if self.svc.decision.jump_onset_id is not None or st is None or not st.rows:
            return None
        x, P = st.estimate()
        return Posterior(x, st.active, P.copy())

    def statement_u95_mm(self, jump_onset_id: int | None = None) -> float | None:
        """U95 [mm] of a point measured now at the window's poses (module docstring), with the
        innovations since `jump_onset_id` (a jump found and not corrected yet); before any
        measurement of the version in force, its prior at the schedule's views (d = 0); None
        before the estimator's start."""
        st = self.state
        if st is None:
            return None
        s = st.settings
        u2 = max(st.s_u_mm**2, self._stated_floor_mm2)  # the unmodelled term, as stated
        if not st.rows:
            prior = self._variance_at_schedule(list(st.active), st.P[: st.L, : st.L])
            return norm_quantile() * math.sqrt(prior + u2 + s.sigma_mm**2)
        d, P = st.posterior()
        # the parameters in force are off by d (the estimator's posterior) with covariance P
        var = [
            (float((r.H @ d) @ (r.H @ d)) + float(np.trace(r.H @ P @ r.H.T))) / 3.0
            + u2
            + s.sigma_mm**2
            for r in st.rows
        ]
        total = float(np.mean(var))
        if jump_onset_id is not None:
            after = [r for r in st.rows if r.obs.ref >= jump_onset_id]
            if after:
                total += float(np.mean([(r.v0 - r.H @ d) @ (r.v0 - r.H @ d) / 3.0 for r in after]))
        return norm_quantile() * math.sqrt(total)

    def summarise(self) -> None:
        """`sphere_summary`: per sphere, its measurements in the window: how many (`n`), the
        newest's residual against the parameters in force (`residual_mm`, its centre's distance
        from where they put it), and their RMS residual against the estimator's posterior
        (`posterior_rms_mm`: what is left once the estimator's drift is taken off). Once a
        window in the loop's thread (the status reply reads it from others: the arrays change
        while a measurement goes in)."""
        st = self.state
        out: dict[str, dict[str, Any]] = {
            k: {"n": 0, "residual_mm": None, "posterior_rms_mm": None} for k in self.svc.spheres
        }
        self.sphere_summary = out
        if st is None or not st.rows:
            return
        d = st.posterior()[0]
        left: dict[str, list[float]] = {}
        for r in st.rows:
            k = r.obs.target
            if k not in out:
                continue
            out[k]["n"] += 1
            out[k]["residual_mm"] = float(np.linalg.norm(r.v0))
            left.setdefault(k, []).append(float(np.linalg.norm(r.v0 - r.H @ d)))
        for k, e in left.items():
            out[k]["posterior_rms_mm"] = math.sqrt(float(np.mean(np.square(e))))

    def n_rows(self) -> int:
        """The measurements the estimator's window holds."""
        return 0 if self.state is None else len(self.state.rows)

    def to_json(self) -> list[float]:
        """The evidence about s_u carried into the version in force (its own comes again from
        replaying its measurements at a start)."""
        return list(self._moments)

    def load_json(self, moments: list[float] | None) -> None:
        self._moments = [float(m) for m in moments or []]
