"""A clamped body's features measured in the cycle (DESIGN.md section 14; PLC handshake in
drivers/plc.py): when the PLC raises body_ready the service measures the body's features by the
part type's plan (`STATE_DIR/features.toml`), between bodies it measures spheres as before.

    body_ready rises (the body id read) -> busy -> per feature of the route: the next view if
    it fits the body's window with the way home, move, sweep, the points extracted -> home ->
    the values computed with the parameters in force and the cell's statement -> stored with
    their raw data (committed) -> body_done, body_nok when a characteristic is proven out of
    tolerance or not measured -> both cleared when body_ready falls

A feature that the time, the PLC (the body withdrawn) or the vision leaves without a value is
"not measured" with its reason; the body's other values stand. The views are planned on the
parameters in force and planned again when another version goes in force
(app.inspect.views; a few seconds).

Re-evaluation (`reevaluate_pending`): a suspect interval that closed with another version in
force (a step found after its bodies were measured, and corrected) has its bodies computed again
from their raw data with that version: a new evaluation beside the earlier one, and the interval
says how many bodies and how many decisions changed. Only the bodies measured after the step's
first moved measurement: one measured between the last trustworthy measurement and it may
precede the step, and the correction would move it wrongly; it stays as measured, suspect, and
the interval counts it (`not_reevaluated`: measure it again).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.api import Calibration
from app.inspect.measure import (
    BodyResult,
    FeatureSensor,
    PointCov,
    RawFeature,
    evaluate_body,
    extract,
)
from app.inspect.plan import FeaturePlan, load_features
from app.inspect.spc import (
    BASELINE_BODIES,
    RECENT_N,
    IndividualsChart,
    Signal,
    add_values,
    attribute,
    grouped_texts,
)
from app.inspect.values import StopNoise, Value
from app.inspect.views import (
    InspectionPlan,
    extra_stop_s,
    first_stop_s,
    plan_views,
    reaimed,
)
from app.line.body_export import ResultsWriter
from app.line.cycle import WindowWatch, Withdrawal
from app.line.measure import SphereMeasurer, SweepFeatureSensor
from app.line.settings import ServiceSettings
from app.line.statedir import StateDir
from app.line.store import Store
from drivers.errors import DeviceError
from vision.features import FeaturePoints
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class BodySetup:
    """What the service needs to measure bodies: the part type's plan, the sensor's sweep of a
    feature and the sensor model (the sweep's mirror commands)."""

    plan: FeaturePlan
    sensor: FeatureSensor
    sensor_model: SensorModel


def feature_plan(state_root: Path, T_part_base: F64) -> FeaturePlan | None:
    """The state directory's feature plan (`features.toml`: its errors are the start's, exit
    2), None without one: the cell measures no body."""
    path = StateDir(state_root).features
    return load_features(path, T_part_base) if path.is_file() else None


def sweep_bodies(
    state_root: Path, T_part_base: F64, camera: Any, galvo: Any, sensor_model: SensorModel
) -> BodySetup | None:
    """A real cell's bodies: the state directory's feature plan measured with the sensor's
    sweeps (app.line.measure.SweepFeatureSensor: the camera and galvo the spheres are measured
    with); None without a plan."""
    plan = feature_plan(state_root, T_part_base)
    if plan is None:
        return None
    return BodySetup(plan, SweepFeatureSensor(camera, galvo, sensor_model), sensor_model)


@dataclass
class BodyReport:
    """One body: its row in the store, id, how many characteristics are nok / undecided / not
    measured, whether the PLC took it back (why), the robot's time [s] and the characteristic
    furthest out of its tolerance."""

    row: int
    body_id: Any
    ok: bool
    n_nok: int
    n_undecided: int
    n_not_measured: int
    withdrawn: str = ""
    robot_s: float = 0.0
    worst: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def summary(values: tuple[Value, ...] | list[Value]) -> dict[str, int]:
    """ok (no characteristic proven out and every one measured), the counts."""
    nok = sum(v.decision == "nonconforming" for v in values)
    und = sum(v.decision == "undecided" for v in values)
    nm = sum(v.decision == "not measured" for v in values)
    return {"ok": int(nok == 0 and nm == 0), "n_nok": nok, "n_undecided": und, "n_not_measured": nm}


def worst_value(values: tuple[Value, ...] | list[Value]) -> dict[str, Any]:
    """The characteristic furthest out of (or nearest to leaving) its tolerance, as a share."""
    best: tuple[float, Value] | None = None
    for v in values:
        if v.deviation_mm is None:
            continue
        lo, hi = v.characteristic.tol_mm
        half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
        share = abs(v.deviation_mm - mid) / half
        if best is None or share > best[0]:
            best = (share, v)
    if best is None:
        return {}
    v = best[1]
    return {"characteristic": v.characteristic.key, "deviation_mm": v.deviation_mm,
            "decision": v.decision}  # fmt: skip


def raw_rows(raw: tuple[RawFeature, ...]) -> list[dict[str, Any]]:
    return [
        {
            "feature": r.feature, "stop": r.stop, "q_deg": r.q_deg, "temp_c": r.temp_c,
            "sheet": None if r.points is None else r.points.sheet_mm,
            "edges": None if r.points is None else r.points.edges_mm, "refused": r.refused,
        }
        for r in raw
    ]  # fmt: skip


def raw_of(rows: Any) -> list[RawFeature]:
    out = []
    for r in rows:
        points = None
        if r["sheet"] is not None:
            edges = r["edges"] if r["edges"] is not None else np.zeros((0, 3))
            points = FeaturePoints(r["sheet"], edges)
        out.append(
            RawFeature(
                r["feature"], r["q_deg"], r["temp_c"], points, r["refused"], int(r.get("stop", 0))
            )
        )
    return out


class BodyCycle:
    """Measures clamped bodies (module docstring) for the service."""

    @classmethod
    def of(
        cls,
        setup: BodySetup,
        s: ServiceSettings,
        watch: WindowWatch,
        measurer: SphereMeasurer,
        store: Store,
    ) -> BodyCycle:
        """The cycle of a service with settings `s` (the sphere measurement's noise resolved):
        the robot's repeatability, the statement's own noise and the sensor's edge allowances
        in the values' U95, the results directory's writer when `[results] dir` is set."""
        writer = None
        if s.results_dir is not None:
            writer = ResultsWriter(s.results_dir, s.station, setup.plan.description)
        noise = StopNoise(
            s.repeatability_mm, s.recalib.jump_sigma_mm, s.sensor_edge_u_mm,
            s.sensor_edge_u_slot_mm,
        )  # fmt: skip
        return cls(setup, watch, measurer, store, noise, writer)

    def __init__(
        self,
        setup: BodySetup,
        watch: WindowWatch,
        measurer: SphereMeasurer,
        store: Store,
        noise: StopNoise,
        writer: ResultsWriter | None = None,
    ) -> None:
        """noise: the robot's repeatability and the statement's own measurement noise
        (app.inspect.values); writer: the results directory's (app.line.body_export; None:
        none)."""
        self.plan, self.sensor, self.sensor_model = setup.plan, setup.sensor, setup.sensor_model
        self.watch, self.measurer, self.store = watch, measurer, store
        self.noise = noise
        self.writer = writer
        self.clock, self.line, self.plc = watch.clock, watch.line, watch.plc
        self._views: tuple[int, InspectionPlan] | None = None
        self._cals: dict[int, Calibration] = {}
        # SPC (app.inspect.spc): the charts, replayed from the stored bodies (a restart is no
        # new baseline): the first ones, which hold every chart's baseline, and the last ones,
        # its recent run (a year of bodies is not read at each start); and the signals waiting
        # for the cell's next window to be attributed
        self.charts: dict[str, IndividualsChart] = {}
        self.signals: list[Signal] = []
        stored = store.bodies()
        head = BASELINE_BODIES
        for b in stored[:head] + stored[max(head, len(stored) - RECENT_N) :]:
            self._chart(b["body_id"], store.body_values(int(b["id"])))
        self.signals.clear()

    def calibration(self, version: int, path: Path) -> Calibration:
        if version not in self._cals:
            while len(self._cals) >= 4:
                self._cals.pop(next(iter(self._cals)))
            self._cals[version] = Calibration.load(path)
        return self._cals[version]

    def views(self, version: int, cal: Calibration) -> InspectionPlan:
        """The route on the parameters in force: planned once, then re-aimed on each new
        version (app.inspect.views.reaimed), planned again when a view does not converge."""
        if self._views is not None and self._views[0] == version:
            return self._views[1]
        route = None if self._views is None else reaimed(self._views[1], cal.model, cal.x)
        if route is None:
            rp = self.noise.repeatability_mm
            route = plan_views(self.line, rp, cal.model, cal.x, self.plan, self.sensor_model)
        self._views = (version, route)
        return route

    def run_body(
        self,
        window: int,
        version: int,
        cal: Calibration,
        statement_u95_mm: float | None,
        temp_c: float | None,
        shared: PointCov | None = None,
    ) -> BodyReport:
        """Measure the body the PLC made ready, store it, tell the PLC; raises a DeviceError
        for a fault. shared: the estimator's shared error at a view (app.inspect.measure)."""
        route = self.views(version, cal)
        w = self.watch
        w.body_used_t = w.body_opened_t
        end_t, body_id = w.body_end_t(), w.body_id
        t_start, t0 = self.clock.time(), self.clock.monotonic()
        self.plc.set_signals(busy=True, done=False, fault=False)
        self.plc.set_body_signals(done=False)
        raw: list[RawFeature] = []
        skipped: dict[str, str] = dict(route.unreachable)
        with Withdrawal(w, self.measurer.robot.abort, w.body_ready) as guard:
            for v in route.views:
                why = self._cannot(v, end_t, guard)
                if why:
                    skipped[v.feature] = why
                    continue
                raw += self._stops(v, cal, temp_c, end_t, guard, skipped)
        if guard.error is not None:
            raise guard.error
        if guard.withdrawn and self.measurer.robot.fault is not None:
            self.measurer.robot.reset()  # our own abort latched it
        self.measurer.go_home()
        result = evaluate_body(
            str(body_id), cal, self.plan, raw, _or_none(statement_u95_mm), skipped,
            self.noise, shared,
        )  # fmt: skip
        row = self._store(result, window, t_start, body_id, version, statement_u95_mm, temp_c)
        self._chart(body_id, [v.as_dict() for v in result.values])
        s = summary(result.values)
        self.plc.set_signals(busy=False, done=False, fault=False)
        self.plc.set_body_signals(done=not guard.withdrawn, nok=not s["ok"])
        return BodyReport(
            row, body_id, bool(s["ok"]), s["n_nok"], s["n_undecided"], s["n_not_measured"],
            guard.why if guard.withdrawn else "", self.clock.monotonic() - t0,
            worst_value(result.values),
        )  # fmt: skip

    def _stops(
        self,
        v: Any,
        cal: Calibration,
        temp_c: float | None,
        end_t: float,
        guard: Withdrawal,
        skipped: dict[str, str],
    ) -> list[RawFeature]:
        """The feature's sweeps from its view's stops (app.inspect.views: between two, the
        robot backs off along the sensor's axis and returns, a new stop), while the body's
        window leaves time for the next; the body withdrawn during the first: none."""
        out: list[RawFeature] = []
        feature = self.plan.feature(v.feature)
        for k in range(v.stops):
            if k and (not self._time_for_stop(v, end_t) or v.q_retreat_deg is None):
                break
            try:
                if k:
                    self.measurer.move_to(v.q_retreat_deg)
                self.measurer.move_to(v.q_deg)
            except DeviceError:
                if not guard.withdrawn:
                    raise
                if not out:
                    skipped[v.feature] = f"the body withdrawn ({guard.why})"
                break
            profiles = self.sensor.profiles(v)
            out.append(extract(cal, feature, v.q_deg, profiles, temp_c, stop=k))
        return out

    def _time_for_stop(self, view: Any, end_t: float) -> bool:
        """Another stop of `view` leaves the rest of the route (every later feature's first
        stop, then home: `rest_s`) its time in the body's window."""
        return self.clock.monotonic() + extra_stop_s(view) <= end_t

    def _cannot(self, view: Any, end_t: float, guard: Withdrawal) -> str:
        """Why the robot does not go to this view now ("" when it does)."""
        if guard.withdrawn:
            return f"the body withdrawn ({guard.why})"
        need = first_stop_s(self.measurer.robot.joints_deg(), view, self.line)
        if self.clock.monotonic() + need > end_t:
            window = self.line.body_window_s
            return f"no time left in the body's window ([line] body_window_s {window:g} s)"
        return ""

    def _store(
        self,
        result: BodyResult,
        window: int,
        t: float,
        body_id: Any,
        version: int,
        statement: float | None,
        temp_c: float | None,
    ) -> int:
        s = summary(result.values)
        evaluation = {
            "t": t, "params_version": version, "statement_u95_mm": statement,
            "reason": "measured", **s,
        }  # fmt: skip
        body = {"t": t, "body_id": body_id, "part": self.plan.part, "window": window,
                "temp_c": temp_c}  # fmt: skip
        return self.store.add_body(
            body, evaluation, [v.as_dict() for v in result.values], raw_rows(result.raw)
        )

    def _chart(self, body_id: Any, values: list[dict[str, Any]]) -> None:
        self.signals += add_values(self.charts, body_id, values)

    def attribute_signals(self, limit_mm: float, now_u95_mm: float | None) -> list[str]:
        """The waiting signals' alarm texts, each with whose it is (app.inspect.spc)."""
        if not self.signals:
            return []
        intervals = self.store.suspects()
        attributed = []
        for sig in self.signals:
            rows = [r for b in sig.bodies for r in self.store.bodies(body_id=b)[-1:]]
            attributed.append((sig, attribute(rows, intervals, limit_mm, now_u95_mm)))
        self.signals.clear()
        return grouped_texts(attributed)

    def export(self) -> tuple[int, str]:
        """The bodies' files not written yet into the results directory: (written, why the
        next could not be); (0, "") without a directory."""
        if self.writer is None:
            return 0, ""
        return self.writer.export_pending(self.store, self.clock.time())

    def clear_result(self) -> None:
        """The body's result bits go when the PLC took the body away (body_ready low)."""
        out = self.plc.outputs
        if (out.body_done or out.body_nok) and not self.watch.body_ready():
            self.plc.set_body_signals(done=False)

    def reevaluate_pending(
        self, params_path: Any, statement_u95_mm: float | None
    ) -> list[dict[str, Any]]:
        """Every closed suspect interval whose correction is another version than its bodies
        were measured with: those bodies computed again with it (module docstring). The
        intervals re-evaluated now, with their counts."""
        done = []
        for interval in self.store.suspects():
            version = interval.get("end_version")
            if interval.get("t_end") is None or version is None:
                continue  # open: its correction is not in force yet
            if interval.get("reevaluated") is not None:
                continue  # handled already (0 included: none could be)
            bodies = self.store.bodies(interval["t_start"], interval["t_end"])
            bodies = [b for b in bodies if b["params_version"] != version]
            if not bodies:  # none measured with another version: nothing to compute again
                self.store.update_suspect(
                    int(interval["id"]), reevaluated=0, decisions_changed=0, not_reevaluated=0
                )
                continue
            t_moved = self._first_moved_t(interval)
            todo = [b for b in bodies if b["t"] >= t_moved]
            changed = 0
            if todo:
                cal = self.calibration(int(version), params_path(int(version)))
                changed = sum(
                    self._reevaluate(b, cal, int(version), statement_u95_mm, int(interval["id"]))
                    for b in todo
                )
            left = len(bodies) - len(todo)
            self.store.update_suspect(
                int(interval["id"]),
                reevaluated=len(todo),
                decisions_changed=changed,
                not_reevaluated=left,
            )
            done.append(
                {"id": interval["id"], "bodies": len(todo), "decisions_changed": changed,
                 "not_reevaluated": left}
            )  # fmt: skip
        return done

    def _first_moved_t(self, interval: dict[str, Any]) -> float:
        """When the step's first moved measurement was taken: the bodies measured since were
        measured with the cell as it was after the step (the correction is theirs); those
        between the interval's start and it may precede the step and are left as measured."""
        rows = self.store.measurements_by_id([int(interval["onset_id"])])
        return float(rows[0]["t"]) if rows else math.inf

    def _reevaluate(
        self,
        body: dict[str, Any],
        cal: Calibration,
        version: int,
        statement_u95_mm: float | None,
        suspect_id: int,
    ) -> int:
        """One body computed again; the number of its decisions that changed."""
        before = {
            (v["feature"], v["characteristic"]): v["decision"]
            for v in self.store.body_values(int(body["id"]))
        }
        raw = raw_of(self.store.body_raw(int(body["id"])))
        result = evaluate_body(
            str(body["body_id"]), cal, self.plan, raw, _or_none(statement_u95_mm), None,
            self.noise,
        )  # fmt: skip
        values = [v.as_dict() for v in result.values]
        changed = sum(
            before.get((v["feature"], v["characteristic"])) != v["decision"] for v in values
        )
        evaluation = {
            "t": self.clock.time(), "params_version": version,
            "statement_u95_mm": statement_u95_mm,
            "reason": f"re-evaluated with version {version}: suspect interval {suspect_id}",
            "suspect_id": suspect_id, "decisions_changed": changed, **summary(result.values),
        }  # fmt: skip
        self.store.add_evaluation(int(body["id"]), evaluation, values)
        return changed


def _or_none(u: float | None) -> float:
    """A statement to compute with: none stated counts as 0 (the calibration's covariance and
    the fit's alone); the evaluation stores it as none."""
    return 0.0 if u is None or not math.isfinite(u) else u
