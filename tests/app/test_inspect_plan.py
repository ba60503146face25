"""The feature plan file (app/inspect/plan.py), its views (app/inspect/views.py), the values'
decisions (app/inspect/values.py) and `rvis inspect plan`: every bad field named by file, line,
feature and field with exit 2; a feature without a view named with exit 3, never dropped."""

from __future__ import annotations

import dataclasses
import itertools
import json
import subprocess
import sys
from math import ceil
from pathlib import Path

import numpy as np
import pytest

from app.config import CellConfig
from app.errors import InputError
from app.inspect.measure import mean_fit
from app.inspect.plan import features_toml, load_features
from app.inspect.values import StopNoise, decide, feature_values
from app.inspect.views import (
    FeatureView,
    InspectionPlan,
    ViewSettings,
    in_window,
    plan_views,
    stops_wanted,
)
from app.motion import motion_time_s
from app.sim.part import default_part
from vision.features import FeatureFit
from vision.sensor_model import default_sensor_model

GOOD = """format = "rvis-features/1"
part = "P-1"
description = "two features"

[[feature]]
id = "H01"
type = "hole"
position_mm = {p1}
normal = [-0.8, 0.0, 0.6]
diameter_mm = 10
position_tol_mm = [-0.5, 0.5]
size_tol_mm = [-0.2, 0.2]

[[feature]]
id = "P01"
type = "surface"
position_mm = {p2}
normal = [-0.8, 0.0, 0.6]
normal_tol_mm = [-0.7, 0.7]
"""


def good(cfg: CellConfig) -> str:
    """GOOD with its features 1400 mm from the J1 axis, in front of the robot (part frame)."""

    def part(p_base: list[float]) -> str:
        p = cfg.T_part_base[:3, :3] @ np.array(p_base) + cfg.T_part_base[:3, 3]
        return "[" + ", ".join(f"{a:.3f}" for a in p) + "]"

    return GOOD.format(p1=part([1400.0, -200.0, 100.0]), p2=part([1400.0, 200.0, 100.0]))


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "features.toml"
    path.write_text(text)
    return path


def test_the_simulated_part_type_reads_back_equal(cfg: CellConfig, tmp_path: Path) -> None:
    plan = default_part(cfg)
    back = load_features(_write(tmp_path, features_toml(plan)), cfg.T_part_base)
    assert len(back.features) >= 20 and len(back.characteristics()) == len(plan.characteristics())
    kinds = {f.type for f in back.features}
    assert kinds == {"hole", "slot", "surface"}
    for a, b in zip(plan.features, back.features, strict=True):
        assert a.id == b.id and a.type == b.type and a.size_mm == b.size_mm
        assert np.allclose(a.position_mm, b.position_mm) and a.tolerances == b.tolerances
    # the simulated fixture's clamping repeatability, as a plant states its fixture's
    assert back.clamp_sd_mm == plan.clamp_sd_mm and 0.01 <= plan.clamp_sd_mm < 0.02


@pytest.mark.parametrize("bad", ["-0.01", '"small"', "true", "12"])
def test_a_bad_clamping_repeatability_is_named_with_its_line(
    cfg: CellConfig, tmp_path: Path, bad: str
) -> None:
    text = good(cfg).replace(
        'description = "two features"\n', f'description = "two"\nclamp_sd_mm = {bad}\n'
    )
    assert load_features(_write(tmp_path, good(cfg))).clamp_sd_mm == 0.0  # not given: none
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as info:
        load_features(path, cfg.T_part_base)
    assert info.value.field == "clamp_sd_mm" and info.value.line == 4
    assert str(path) in str(info.value) and "from 0 to 10" in str(info.value)


@pytest.mark.parametrize(
    ("old", "new", "line", "field", "words"),
    [
        ('type = "hole"', 'type = "stud"', 7, "type", "unknown type 'stud'"),
        ("size_tol_mm = [-0.2, 0.2]", "", 5, "size_tol_mm", "missing"),
        ("size_tol_mm = [-0.2, 0.2]", "size_tol_mm = [0.2, -0.2]", 12, "size_tol_mm", "inverted"),
        ('id = "P01"', 'id = "H01"', 15, "id", "duplicate id 'H01'"),
        ("position_mm = {p2}", "position_mm = [4000.0, 200.0, 100.0]", 17, "position_mm", "reach"),
        (
            "normal = [-0.8, 0.0, 0.6]\ndiameter",
            "normal = [0, 0, 0]\ndiameter",
            9,
            "normal",
            "zero",
        ),
        ("diameter_mm = 10", "diameter_mm = 'ten'", 10, "diameter_mm", "expected a number"),
    ],
)
def test_a_bad_field_is_named_with_its_line_and_feature(
    cfg: CellConfig, tmp_path: Path, old: str, new: str, line: int, field: str, words: str
) -> None:
    if "{p2}" in old:  # the second feature moved out of reach, the first where it was
        head, tail = good(cfg).split('[[feature]]\nid = "P01"')
        text = head + '[[feature]]\nid = "P01"' + tail.replace(tail.split("\n")[2], new)
    else:
        text = good(cfg).replace(old, new, 1)
    assert text != good(cfg)
    path = _write(tmp_path, text)
    with pytest.raises(InputError) as info:
        load_features(path, cfg.T_part_base)
    err = info.value
    assert err.field == field and words in str(err)
    assert err.line == line, str(err)
    assert str(path) in str(err) and "feature '" in str(err)


def test_iso_14253_decisions() -> None:
    tol = (-0.5, 0.5)
    assert decide(0.30, tol, 0.1) == "conforming"
    assert decide(0.45, tol, 0.1) == "undecided"  # inside, but within U of the limit
    assert decide(0.55, tol, 0.1) == "undecided"  # outside, but within U of the limit
    assert decide(0.61, tol, 0.1) == "nonconforming"
    assert decide(-0.61, tol, 0.1) == "nonconforming"


def test_every_feature_of_the_part_type_has_a_view_seeing_it_where_planned(
    cfg: CellConfig,
) -> None:
    model = cfg.model()
    x = model.nominal_x()
    plan = default_part(cfg)
    route = plan_views(cfg.line, 0.07, model, x, plan, default_sensor_model())
    assert route.unreachable == {} and len(route.views) == len(plan.features)
    for v in route.views:
        T = model.fk(x, v.q_deg[None])[0]
        f = plan.feature(v.feature)
        c = T[:3, :3].T @ (f.position_mm - T[:3, 3])
        assert np.allclose(c, [0.0, 0.0, 120.0], atol=1e-3)
        # the sensor looks at the sheet within 10 degrees of its normal, never upward
        assert T[:3, 2] @ -f.normal > np.cos(np.radians(10.5)) and T[2, 2] <= 1e-9
        assert 0.005 < v.repeat_sd_mm < 0.05 and len(v.commands_v) >= 10
    assert route.route_s > 0


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "app", "inspect", "plan", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_rvis_inspect_plan_names_the_feature_it_cannot_reach(
    cfg: CellConfig, tmp_path: Path
) -> None:
    """A hole on a sheet facing away from the robot: no view within the tilt limit; exit 3,
    the feature named, the other planned and written."""
    params = tmp_path / "params.json"
    sim = subprocess.run(
        [sys.executable, "-m", "app", "simulate", "--out", str(tmp_path / "sim")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    ident = subprocess.run(
        [sys.executable, "-m", "app", "identify", "--targets",
         str(tmp_path / "sim/calibration_targets.csv"), "--measurements",
         str(tmp_path / "sim/calibration_measurements.csv"), "--out", str(params)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert ident.returncode == 0, ident.stderr
    away = good(cfg).replace(
        "normal = [-0.8, 0.0, 0.6]\ndiameter", "normal = [0.8, 0.0, -0.6]\ndiameter"
    )
    features = _write(tmp_path, away)
    sensor = tmp_path / "sensor.toml"
    from vision.sensor_model import save_sensor_model

    save_sensor_model(default_sensor_model(), sensor)
    out = tmp_path / "route.json"
    r = _run("--params", str(params), "--sensor", str(sensor), "--features", str(features),
             "--out", str(out))  # fmt: skip
    assert r.returncode == 3, r.stderr
    assert "feature H01: no view" in r.stderr
    doc = json.loads(out.read_text())
    assert [v["feature"] for v in doc["views"]] == ["P01"] and "H01" in doc["unreachable"]
    # a plan without the fixture's clamping repeatability: said, not silently left out
    assert doc["clamp_sd_mm"] == 0.0 and "clamping repeatability not given" in r.stdout
    bad = _write(tmp_path, good(cfg).replace('type = "hole"', 'type = "stud"'))
    r = _run("--params", str(params), "--sensor", str(sensor), "--features", str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "field 'type'" in r.stderr


def test_a_new_version_re_aims_the_route_instead_of_planning_again(cfg: CellConfig) -> None:
    from app.inspect.views import reaimed

    model = cfg.model()
    x = model.nominal_x()
    plan = default_part(cfg)
    route = plan_views(cfg.line, 0.07, model, x, plan, default_sensor_model())
    x2 = x + np.random.default_rng(3).normal(0.0, 1e-4, x.shape)  # another version, near
    again = reaimed(route, model, x2)
    assert again is not None
    assert [v.feature for v in again.views] == [v.feature for v in route.views]
    for v, old in zip(again.views, route.views, strict=True):
        assert not np.allclose(v.q_deg, old.q_deg)  # moved to the new parameters ...
        assert np.allclose(model.fk(x2, v.q_deg[None])[0], v.T_part_sensor, atol=1e-6)
        assert np.array_equal(v.commands_v, old.commands_v)  # ... the same sweep


def test_a_feature_the_robot_repeats_too_little_for_is_measured_from_several_stops(
    cfg: CellConfig,
) -> None:
    """A type-1 study asks s <= 0.2 T / (6 x 1.33) of one measurement: a view whose robot
    share is above 0.8 of that gets as many stops as bring it within (at most 3), each a
    back-off along the sensor's axis; the others one. Each view knows the rest of the route
    after its first stop (the cell's time for an extra stop)."""
    model = cfg.model()
    x = model.nominal_x()
    plan = default_part(cfg)
    s = ViewSettings()
    route = plan_views(cfg.line, 0.07, model, x, plan, default_sensor_model())
    for v in route.views:
        f = plan.feature(v.feature)
        width = min(hi - lo for c in f.characteristics() if c.kind == "position"
                    for lo, hi in [c.tol_mm])  # fmt: skip
        allowed = 0.8 * 0.2 * width / (6 * 1.33)
        wanted = min(3, max(1, ceil((v.repeat_sd_mm / allowed) ** 2)))
        assert v.stops == stops_wanted(v, f, s) == wanted
        if v.stops > 1:
            assert v.q_retreat_deg is not None and v.retreat_s > 0
            T = model.fk(x, v.q_retreat_deg[None])[0]
            back = T[:3, :3].T @ (f.position_mm - T[:3, 3])
            assert np.allclose(back, [0.0, 0.0, 140.0], atol=1e-2)  # backed off 20 mm
    assert any(v.stops > 1 for v in route.views) and any(v.stops == 1 for v in route.views)
    rests = [v.rest_s for v in route.views]
    assert all(a > b for a, b in itertools.pairwise(rests)) and rests[-1] > 0
    first = sum(v.motion_s + v.sweep_s for v in route.views) + rests[-1]
    extra = sum((v.stops - 1) * (v.retreat_s + v.sweep_s) for v in route.views)
    assert route.route_s == pytest.approx(first + extra)


def test_the_fits_of_several_stops_are_averaged() -> None:
    """Each stop's fit its own robot error: their mean, the fit's own covariance and a size's
    standard deviation divided by their number."""
    fits = [
        FeatureFit("hole", np.array([1.0, 2.0, 0.0]), np.array([0.0, 0.0, 1.0]), (12.01,),
                   np.zeros(3), 0.0, np.eye(3) * 4e-6, (0.003,), 40, 0.9, 0.01, 0.01),
        FeatureFit("hole", np.array([1.02, 1.98, 0.0]), np.array([0.0, 0.0, 1.0]), (11.99,),
                   np.zeros(3), 0.0, np.eye(3) * 4e-6, (0.003,), 38, 0.9, 0.01, 0.01),
    ]  # fmt: skip
    m = mean_fit(fits)
    assert np.allclose(m.centre_mm, [1.01, 1.99, 0.0]) and m.size_mm == pytest.approx((12.0,))
    assert np.allclose(m.cov_centre_mm2, np.eye(3) * 2e-6)
    assert m.sd_size_mm == pytest.approx((0.003 / np.sqrt(2),)) and m.n_edge_points == 78
    assert mean_fit(fits[:1]) is fits[0]


def test_a_value_holds_its_own_stops_repeatability_in_place_of_the_statements_noise(
    cfg: CellConfig,
) -> None:
    """The cell's statement holds its own measurement's noise (a sphere's stop: sigma_m); a
    feature's value holds its view's robot repeatability over its n stops in its place: its
    U95 is k sqrt(sigma_cell^2 - sigma_m^2 + r^2 / n) along each axis; with neither known, the
    statement as it is; the fixture's clamping repeatability adds to a position's."""
    f = default_part(cfg).features[0]
    fit = FeatureFit("hole", f.position_mm.copy(), f.normal, f.size_mm, np.zeros(3), 0.0,
                     np.zeros((3, 3)), (0.002,), 40, 0.9, 0.01, 0.01)  # fmt: skip

    def u95(stops: int, rep: np.ndarray | None, noise_mm: float) -> dict[str, float | None]:
        values = feature_values(f, fit, np.zeros((3, 3)), 0.08, stops, rep, noise_mm)
        return {v.characteristic.name: v.u95_mm for v in values}

    sigma2 = (0.08 / 2.795483) ** 2
    plain = u95(1, None, 0.0)
    assert plain["X"] == pytest.approx(1.959964 * np.sqrt(sigma2), rel=1e-4)
    rep = np.diag([0.03, 0.01, 0.0]) ** 2
    one, two = u95(1, rep, 0.02), u95(2, rep, 0.02)
    for name, r2 in (("X", 0.03**2), ("Y", 0.01**2), ("Z", 0.0)):
        for n, got in ((1, one), (2, two)):
            want = 1.959964 * np.sqrt(sigma2 - 0.02**2 + r2 / n)
            assert got[name] == pytest.approx(want, rel=1e-4)
    # a view that repeats worse than the sphere's stop states more than the cell, a better one
    # less; the same noise without the view's repeatability: the statement once a stop
    assert (one["X"] or 0.0) > (plain["X"] or 0.0) > (one["Y"] or 0.0)
    assert u95(1, None, 0.02)["X"] == pytest.approx(plain["X"])
    # the fixture's clamping repeatability: in every position value, in no size
    clamped = feature_values(f, fit, np.zeros((3, 3)), 0.08, 1, None, 0.0, 0.01)
    got = {v.characteristic.name: v.u95_mm for v in clamped}
    assert got["X"] == pytest.approx(1.959964 * np.sqrt(sigma2 + 0.01**2), rel=1e-4)
    assert got["D"] == plain["D"]
    # the sensor's edge allowance ([sensor] edge_u_mm) in every size, in no position
    edged = feature_values(f, fit, np.zeros((3, 3)), 0.08, 1, None, 0.0, edge_u_mm=0.005)
    got = {v.characteristic.name: v.u95_mm for v in edged}
    assert got["D"] == pytest.approx(1.959964 * np.sqrt(0.002**2 + 2 * 0.005**2), rel=1e-4)
    assert got["X"] == plain["X"]
    # a slot's allowance ([sensor] edge_u_slot_mm) for a slot's sizes, a hole's for a hole's
    noise = StopNoise(edge_u_mm=0.002, edge_u_slot_mm=0.006)
    assert (noise.edge_u("slot"), noise.edge_u("hole"), noise.edge_u("surface")) == (
        0.006, 0.002, 0.002,
    )  # fmt: skip
    assert two["D"] == one["D"]  # a size: within one view, no pose error
    # the estimator's shared error at the view, where it says more than the statement's share
    # along a direction (a warming arm's error along Z is Z's, not a third of a norm)
    shared = np.diag([0.002, 0.004, 0.05]) ** 2
    at_view = feature_values(f, fit, np.zeros((3, 3)), 0.08, 1, None, 0.0, 0.01, shared)
    got = {v.characteristic.name: v.u95_mm for v in at_view}
    for name, var in (("X", sigma2), ("Y", sigma2), ("Z", 0.05**2)):
        assert got[name] == pytest.approx(1.959964 * np.sqrt(var + 0.01**2), rel=1e-4)
    assert got["D"] == plain["D"]


def test_the_bodys_window_holds_the_first_stops_then_the_extra_ones_that_leave_the_rest_time(
    cfg: CellConfig,
) -> None:
    """`in_window` as the cycle decides on the plan's times (app.line.body_cycle): every
    view's first stop while it and the way home fit, an extra stop while the rest of the
    route still fits after it; a window too short cuts the last views."""
    line = dataclasses.replace(cfg.line, body_window_s=100.0)
    home = np.asarray(line.home_deg, dtype=float)
    qs = [home + np.array([10.0 * (k + 1), 0, 0, 0, 0, 0]) for k in range(3)]
    legs = [motion_time_s(a, b, line) for a, b in zip([home, *qs[:-1]], qs, strict=True)]
    back = motion_time_s(qs[-1], home, line)
    views: list[FeatureView] = []
    rest = back
    for k in (2, 1, 0):
        views.insert(
            0,
            FeatureView(f"F{k}", qs[k], np.zeros(3), np.zeros(2), 0.0, legs[k], 1.0,
                        stops=2, q_retreat_deg=qs[k], retreat_s=1.5, rest_s=rest),
        )  # fmt: skip
        rest += legs[k] + 1.0
    route = InspectionPlan(tuple(views), {}, 0.0)
    first = sum(legs) + 3 * 1.0 + back
    fit = in_window(route, line)
    assert (fit.extra_stops, fit.extra_stops_wanted, fit.features_cut) == (3, 3, 0)
    assert fit.robot_s == pytest.approx(first + 3 * 2.5)
    # room for the first stops and one extra stop only: the first view's
    tight = in_window(route, dataclasses.replace(line, body_window_s=first + 3.0))
    assert (tight.extra_stops, tight.features_cut) == (1, 0)
    # not even the last view's first stop
    short = in_window(route, dataclasses.replace(line, body_window_s=first - 0.5))
    assert short.features_cut == 1 and short.extra_stops == 0
