"""The feature plan file (app/inspect/plan.py), its views (app/inspect/views.py), the values'
decisions (app/inspect/values.py) and `rvis inspect plan`: every bad field named by file, line,
feature and field with exit 2; a feature without a view named with exit 3, never dropped."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.config import CellConfig
from app.errors import InputError
from app.inspect.plan import features_toml, load_features
from app.inspect.values import decide
from app.inspect.views import plan_views
from app.sim.part import default_part
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
