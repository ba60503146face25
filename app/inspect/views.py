"""A view per feature on the calibrated model, the galvo sweep across it, and a route through
the views (`rvis inspect plan`).

A view looks at the feature along its normal (the sensor's z axis = -normal, tilted up to
`max_tilt_deg` off it when the straight view is not reachable), with the feature's centre at the
working distance on the sensor's axis: the sheet is inside the depth of field, the laser meets it
at the sensor's triangulation angle (30 degrees, the incidence the sensor is built for). A slot's
long axis lies along the sweep (the sensor's x) turned by SLOT_ROLL_DEG, so the stripes cut
across its width and its length fits the 37 mm of the field of view; the turn makes the stripes
meet its long edges at every phase of the camera's rows (a long edge parallel to the sweep is
met at the same row phase by every stripe: its sub-sample placement error would be one error
for the whole side, up to half a row's step on the width, instead of averaging out).

The joints come from the closed-form inverse kinematics refined on the calibrated model
(calib.ik_refine); every branch within the joint limits, every roll and tilts up to
`prefer_tilt_deg` are candidates. The robot does not repeat
every configuration alike: a joint's error moves the feature by its lever, so the candidates are
ranked by the standard deviation the robot's repeatability (the data sheet's RP as joint errors,
calib.repeatability) gives the feature's position along its worst axis, those within
`repeat_slack` of the best are kept, and the route takes the one nearest the previous view. A
feature with no view is named, never dropped (`InspectionPlan.unreachable`).

Stops: a type-1 study asks s <= 0.2 T / (6 Cg) of one measurement (0.025 mm for T = 1 mm at
Cg 1.33), and the robot's repeatability alone can take a feature's best view past it. Such a
feature is measured from several stops (`stops_wanted`: as many as bring the robot's share
within `repeat_share` of it, at most `max_stops`), the robot backing off along the sensor's
axis and returning between them (a new stop: a new pose error), the fits averaged
(app.inspect.measure). The cell takes an extra stop only while the rest of the route still
fits the body's window (`rest_s`, app.line.body_cycle): every feature's first stop comes first.

The sweep: the mirror commands that put the stripe, on the sheet at the working distance, at
evenly spaced positions across the feature's width plus a margin (the sensor model's laser
planes, vision.sensor_model), `frames` of them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from app.config.line import LineSettings
from app.inspect.plan import Feature, FeaturePlan
from app.motion import motion_time_s, shortest_route
from calib import ik
from calib.candidates import flange_poses, look_rotations
from calib.ik_refine import refine
from calib.model import SystemModel
from calib.repeatability import JOINT_OFFSETS, joint_sigma_rad
from calib.transforms import inverse
from vision.sensor_model import SensorModel

F64 = NDArray[np.float64]
#: a slot's long axis turned this far off the sweep direction [deg] (module docstring)
SLOT_ROLL_DEG = 15.0


@dataclass(frozen=True)
class ViewSettings:
    """working_distance_mm: the sheet's distance along the sensor's axis; max_tilt_deg: how far
    the view may tilt off the feature's normal (prefer_tilt_deg: the tilts every candidate is
    drawn from while one is reachable there); repeat_slack: candidates whose repeatability is
    within this share of the best one's are kept, at most max_candidates (module docstring);
    margin_mm: the sweep's reach beyond the feature's outline (the sheet's plane needs points
    around it); frames per sweep; frame_s per frame (galvo, exposure, transfer);
    surface_span_mm: a surface point's sweep. Stops (module docstring): a feature the robot
    repeats worse at its view than `repeat_share` of what a type-1 study's Cg of `cg_target`
    allows its position tolerance is measured from up to `max_stops` stops, the robot backing
    off `retreat_mm` along the sensor's axis between them."""

    working_distance_mm: float = 120.0
    max_tilt_deg: float = 30.0
    prefer_tilt_deg: float = 10.0
    repeat_slack: float = 0.05
    max_candidates: int = 48
    margin_mm: float = 3.0
    frames: int = 40
    frame_s: float = 0.025
    surface_span_mm: float = 10.0
    cg_target: float = 1.33
    repeat_share: float = 0.8
    max_stops: int = 3
    retreat_mm: float = 20.0


@dataclass(frozen=True)
class FeatureView:
    """A feature's view: q_deg (6,) [controller deg], the feature's centre c_sensor_mm (3,)
    where the calibrated model puts it, the sweep's commands_v (n,) [V], tilt_deg off the
    normal, the motion time to it from the previous view and the sweep's time [s], and the
    standard deviation [mm] the robot's repeatability gives the feature on its worst axis."""

    feature: str
    q_deg: F64
    c_sensor_mm: F64
    commands_v: F64
    tilt_deg: float
    motion_s: float = 0.0
    sweep_s: float = 0.0
    repeat_sd_mm: float = 0.0
    T_part_sensor: F64 = field(default_factory=lambda: np.eye(4))  # the pose it plans
    stops: int = 1  # sweeps from as many stops, averaged (module docstring)
    q_retreat_deg: F64 | None = None  # where the robot backs off to between two stops
    retreat_s: float = 0.0  # the motion time there and back
    rest_s: float = 0.0  # the route after this view's first stop: the later views and home


@dataclass(frozen=True)
class InspectionPlan:
    """Views in route order, the features without a view (id -> reason), and the robot time
    of the route from home and back [s]."""

    views: tuple[FeatureView, ...]
    unreachable: dict[str, str] = field(default_factory=dict)
    route_s: float = 0.0

    def view(self, feature_id: str) -> FeatureView:
        for v in self.views:
            if v.feature == feature_id:
                return v
        raise KeyError(feature_id)


def plan_views(
    line: LineSettings,
    repeatability_mm: float,
    model: SystemModel,
    x: F64,
    plan: FeaturePlan,
    sensor: SensorModel,
    settings: ViewSettings | None = None,
) -> InspectionPlan:
    """A view for each feature of `plan` on the calibrated model (model, x) and the route
    through them from the cell's home (`line`: its home and motion-time model), the robot's
    pose repeatability RP [mm] ranking the candidates (module docstring)."""
    s = settings or ViewSettings()
    home = np.asarray(line.home_deg, dtype=float)
    options: dict[str, list[tuple[F64, F64, float, float]]] = {}
    unreachable: dict[str, str] = {}
    sigma_rad = joint_sigma_rad(model, x, float(repeatability_mm))
    for f in plan.features:
        found = _options(model, x, f, s, sigma_rad)
        if found:
            options[f.id] = found
        else:
            unreachable[f.id] = (
                f"no reachable view within {s.max_tilt_deg:g} deg of its normal at"
                f" {s.working_distance_mm:g} mm"
            )
    ids = list(options)
    first = [min(options[i], key=lambda o: motion_time_s(home, o[0], line)) for i in ids]
    order = shortest_route([o[0] for o in first], home, line)
    views: list[FeatureView] = []
    prev = home
    for k in order:
        fid = ids[k]
        q, c, tilt, sd = min(options[fid], key=lambda o: motion_time_s(prev, o[0], line))
        f = plan.feature(fid)
        cmds = sweep_commands(sensor, f, c, s)
        motion = motion_time_s(prev, q, line)
        T = model.fk(x, q[None])[0]
        views.append(FeatureView(fid, q, c, cmds, tilt, motion, len(cmds) * s.frame_s, sd, T))
        prev = q
    total = sum(v.motion_s + v.sweep_s for v in views)
    total += motion_time_s(prev, home, line)
    views, total = _with_stops(views, plan, model, x, line, s, total)
    return InspectionPlan(tuple(views), unreachable, total)


def stops_wanted(view: FeatureView, feature: Feature, s: ViewSettings) -> int:
    """How many stops the feature's view asks for: the robot's standard deviation there on
    its worst axis (`repeat_sd_mm`) against `repeat_share` of what a type-1 study's Cg of
    `cg_target` allows the narrowest position tolerance, 0.2 T / (6 Cg); averaged over n stops
    it falls by sqrt(n). At most `max_stops`."""
    widths = [hi - lo for c in feature.characteristics() if c.kind == "position"
              for lo, hi in [c.tol_mm]]  # fmt: skip
    if not widths or view.repeat_sd_mm <= 0.0:
        return 1
    allowed = s.repeat_share * 0.2 * min(widths) / (6.0 * s.cg_target)
    return int(min(s.max_stops, max(1, math.ceil((view.repeat_sd_mm / allowed) ** 2))))


def _with_stops(
    views: list[FeatureView],
    plan: FeaturePlan,
    model: SystemModel,
    x: F64,
    line: LineSettings,
    s: ViewSettings,
    total_s: float,
) -> tuple[list[FeatureView], float]:
    """The views with their stops (`stops_wanted`), each extra stop a back-off along the
    sensor's axis and the sweep again, and what the route takes after each view's first stop
    (`rest_s`: the cell measures an extra stop only while the rest of the route still fits the
    body's window, app.line.body_cycle); the route's time with every stop."""
    out = list(views)
    for k, v in enumerate(out):
        n = stops_wanted(v, plan.feature(v.feature), s)
        if n < 2:
            continue
        back = v.T_part_sensor @ _shift_z(-s.retreat_mm)
        fit = refine(model, x, back[None], v.q_deg[None], max_iter=10)
        if not fit.converged[0]:
            continue
        q_r = fit.q_deg[0]
        retreat = 2.0 * motion_time_s(v.q_deg, q_r, line)
        total_s += (n - 1) * (retreat + v.sweep_s)
        out[k] = dataclasses.replace(v, stops=n, q_retreat_deg=q_r, retreat_s=retreat)
    home = np.asarray(line.home_deg, dtype=float)
    rest = motion_time_s(out[-1].q_deg, home, line) if out else 0.0
    for k in range(len(out) - 1, -1, -1):
        out[k] = dataclasses.replace(out[k], rest_s=rest)
        rest += out[k].motion_s + out[k].sweep_s
    return out, total_s


def _shift_z(dz_mm: float) -> F64:
    T = np.eye(4)
    T[2, 3] = dz_mm
    return T


def reaimed(route: InspectionPlan, model: SystemModel, x: F64) -> InspectionPlan | None:
    """The route's views on other parameters (another version in force): each view's joints
    refined on (model, x) to the sensor pose it planned, the route and its sweeps kept (a
    version moves a view by tenths of a millimetre: the same branch, the same sweep). None
    when a view does not converge there (plan again)."""
    if not route.views:
        return route
    T = np.array([v.T_part_sensor for v in route.views])
    q0 = np.array([v.q_deg for v in route.views])
    fit = refine(model, x, T, q0, max_iter=10)
    if not np.all(fit.converged):
        return None
    views = tuple(
        dataclasses.replace(v, q_deg=q) for v, q in zip(route.views, fit.q_deg, strict=True)
    )
    return dataclasses.replace(route, views=views)


def _options(
    model: SystemModel, x: F64, f: Feature, s: ViewSettings, sigma_rad: float
) -> list[tuple[F64, F64, float, float]]:
    """(q_deg, c_sensor_mm, tilt_deg, repeat_sd_mm) of the reachable views of f that the robot
    repeats best (module docstring): the closed form's solutions at tilts up to
    prefer_tilt_deg (else the least tilt up to max_tilt_deg with one) ranked on the model, the
    best refined on it."""
    R_base_part = inverse(model.T_part_base(x))[:3, :3]
    n_base = R_base_part @ f.normal
    a_base = R_base_part @ (f.axis if f.type == "slot" else np.zeros(3))
    c = np.array([0.0, 0.0, s.working_distance_mm])
    steps = np.arange(0.0, s.max_tilt_deg + 1e-9, 5.0)
    # the preferred tilts together, then each larger one alone until one has a solution
    batches: list[list[float]] = [
        [float(t) for t in steps if t <= s.prefer_tilt_deg],
        *([float(t)] for t in steps if t > s.prefer_tilt_deg),
    ]
    for batch in batches:
        Rs = [_rotations(n_base, a_base, float(t)) for t in batch]
        F = np.concatenate([flange_poses(model, x, f.position_mm, R, c) for R in Rs])
        tilt_of = np.concatenate(
            [np.full(len(R), float(t)) for R, t in zip(Rs, batch, strict=True)]
        )
        sols = ik.solve(F, model.limits)
        if len(sols.q_deg):
            break
    else:
        return []
    sd = repeat_sd_mm(model, x, sols.q_deg, c, sigma_rad)
    order = np.argsort(sd, kind="stable")[: s.max_candidates]
    keep = order[sd[order] <= sd[order[0]] * (1 + s.repeat_slack) + 1e-12]
    idx = sols.pose_index[keep]
    target = model.T_part_base(x) @ F[idx] @ model.T_flange_sensor(x)
    fit = refine(model, x, target, sols.q_deg[keep], max_iter=10)
    ok = np.flatnonzero(fit.converged)
    c_s = model.points_sensor(x, fit.q_deg[ok], f.position_mm)
    return [
        (fit.q_deg[j], c_s[n], float(tilt_of[idx[j]]), float(sd[keep[j]])) for n, j in enumerate(ok)
    ]


def repeat_sd_mm(model: SystemModel, x: F64, q_deg: F64, c_sensor_mm: F64, sigma_rad: float) -> F64:
    """The standard deviation [mm] (K,) of the point c_sensor_mm (3,) seen from each of q_deg
    (K, 6) on its worst axis of the part frame, from independent errors of sigma_rad at
    every physical joint: the model's Jacobian of the point by the joints' offsets."""
    q = np.atleast_2d(q_deg)
    c = np.broadcast_to(c_sensor_mm, (len(q), 3))
    J = model.point_jacobian(x, q, c, JOINT_OFFSETS)  # (K, 3 axes, 6 joints)
    out: F64 = sigma_rad * np.sqrt(np.max(np.sum(J**2, axis=2), axis=1))
    return out


def _rotations(n_base: F64, axis_base: F64, tilt_deg: float) -> F64:
    """Sensor orientations (K, 3, 3) looking along -n tilted by tilt_deg in 8 directions
    (one at 0), each at 24 rolls; a slot's: x along its axis turned by +-SLOT_ROLL_DEG, either
    way round (four rolls)."""
    view = -n_base / np.linalg.norm(n_base)
    dirs = [view]
    if tilt_deg > 0:
        e1 = np.cross(view, [0.0, 0.0, 1.0] if abs(view[2]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(view, e1)
        t = np.radians(tilt_deg)
        dirs = [
            np.cos(t) * view + np.sin(t) * (np.cos(b) * e1 + np.sin(b) * e2)
            for b in np.radians(np.arange(0, 360, 45))
        ]
    out = []
    for d in dirs:
        if d[2] > 1e-9:  # the sensor never looks upward
            continue
        if np.linalg.norm(axis_base) > 0:
            a = axis_base - (axis_base @ d) * d
            a /= np.linalg.norm(a)
            for roll in np.radians([SLOT_ROLL_DEG, -SLOT_ROLL_DEG]):
                for sign in (1.0, -1.0):
                    x = sign * (np.cos(roll) * a + np.sin(roll) * np.cross(d, a))
                    out.append(np.column_stack([x, np.cross(d, x), d]))
        else:
            out.extend(look_rotations(np.tile(d, (24, 1)), np.radians(np.arange(0, 360, 15))))
    return np.array(out).reshape(-1, 3, 3)


def sweep_commands(sensor: SensorModel, f: Feature, c_sensor_mm: F64, s: ViewSettings) -> F64:
    """Mirror commands [V] putting the stripe evenly across the feature at its depth: over its
    extent along the sensor's x plus margin_mm each side (a surface point: surface_span_mm)."""
    if f.type == "surface":
        half = 0.5 * s.surface_span_mm
        n = max(s.frames // 4, 6)
    else:
        half = 0.5 * max(f.size_mm) + s.margin_mm
        n = s.frames
    xs = c_sensor_mm[0] + np.linspace(-half, half, n)
    grid = np.linspace(-6.0, 6.0, 1201)
    normals, offsets = sensor.laser.planes(grid)
    z = float(c_sensor_mm[2])
    x_at = (offsets - normals[:, 1] * c_sensor_mm[1] - normals[:, 2] * z) / normals[:, 0]
    order = np.argsort(x_at)
    out: F64 = np.interp(xs, x_at[order], grid[order])
    return out


@dataclass(frozen=True)
class WindowFit:
    """What of a route one body's window holds, as the cycle decides it (app.line.body_cycle)
    on the plan's times: the extra stops taken of those wanted, the features cut (no time left
    for even their first stop), and the robot's time [s] from home and back."""

    window_s: float
    extra_stops: int
    extra_stops_wanted: int
    features_cut: int
    robot_s: float

    def as_dict(self) -> dict[str, float | int]:
        return dataclasses.asdict(self)


def first_stop_s(q_from_deg: F64, view: FeatureView, line: LineSettings) -> float:
    """The time [s] to go from q_from_deg to `view`, sweep its first stop and be home: the
    cycle goes to a view only while this fits the body's window (app.line.body_cycle)."""
    home = np.asarray(line.home_deg, dtype=float)
    go = motion_time_s(q_from_deg, view.q_deg, line)
    return go + view.sweep_s + motion_time_s(view.q_deg, home, line)


def extra_stop_s(view: FeatureView) -> float:
    """The time [s] another stop of `view` leaves the rest of the route: backing off and back,
    the sweep, then every later view's first stop and home (`rest_s`); the cycle takes it only
    while this fits the body's window."""
    return view.retreat_s + view.sweep_s + view.rest_s


def in_window(route: InspectionPlan, line: LineSettings) -> WindowFit:
    """The route in `[line] body_window_s` (`WindowFit`), on the plan's times by the cycle's
    rule: a view is gone to while `first_stop_s` fits, an extra stop taken while
    `extra_stop_s` fits."""
    window = float(line.body_window_s)
    home = np.asarray(line.home_deg, dtype=float)
    t, extra, cut, q = 0.0, 0, 0, home
    for v in route.views:
        if t + first_stop_s(q, v, line) > window:
            cut += 1
            continue
        t, q = t + motion_time_s(q, v.q_deg, line) + v.sweep_s, v.q_deg
        for _ in range(1, v.stops):
            if v.q_retreat_deg is None or t + extra_stop_s(v) > window:
                break
            t += v.retreat_s + v.sweep_s
            extra += 1
    wanted = sum(v.stops - 1 for v in route.views)
    return WindowFit(window, extra, wanted, cut, t + motion_time_s(q, home, line))


def route_table(plan: InspectionPlan) -> list[dict[str, object]]:
    """The views as rows for a report (JSON-ready)."""
    return [
        {
            "feature": v.feature,
            "q_deg": [round(float(a), 3) for a in v.q_deg],
            "c_sensor_mm": [round(float(a), 3) for a in v.c_sensor_mm],
            "tilt_deg": v.tilt_deg,
            "frames": len(v.commands_v),
            "motion_s": round(v.motion_s, 3),
            "sweep_s": round(v.sweep_s, 3),
            "repeat_sd_mm": round(v.repeat_sd_mm, 4),
            "stops": v.stops,
        }
        for v in plan.views
    ]
