"""The API example of docs/api.md runs as written, and its results match the simulated cell's
true robot; the shapes `to_part` accepts; every function checks its arguments and names the
wrong one; a parameters file of another model is refused."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.api import Calibration, command_xyzwpr
from app.errors import InputError
from calib.transforms import apply
from calib.wpr import pose_from_xyzwpr, xyzwpr_from_pose
from tests.inuse.conftest import Calibrated, standoff_error_mm

DOC = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def example_code() -> str:
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_the_documented_example_runs_and_matches_the_true_robot(
    calibrated: Calibrated, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    shutil.copy(calibrated.params, tmp_path / "params.json")
    monkeypatch.chdir(tmp_path)
    ns: dict[str, object] = {}
    exec(compile(example_code(), str(DOC), "exec"), ns)
    cell, model = calibrated.cell, calibrated.model
    q = np.asarray(ns["q_deg"])
    profiles_sensor = np.asarray(ns["profiles_sensor_mm"])
    true_part = apply(cell.T_part_sensor(q)[:, None], profiles_sensor)
    nominal_part = apply(model.fk(model.nominal_x(), q)[:, None], profiles_sensor)
    got = np.asarray(ns["profiles_part_mm"])
    assert got.shape == (2, 3, 3)
    assert np.linalg.norm(got - true_part, axis=-1).max() < 0.2
    assert np.linalg.norm(nominal_part - true_part, axis=-1).min() > 0.5
    # compensated joints: the true robot where the nominal model says the taught joints go
    T_taught = model.fk(model.nominal_x(), q)
    assert standoff_error_mm(cell, q, T_taught).min() > 0.5
    assert standoff_error_mm(cell, np.asarray(ns["send_deg"]), T_taught).max() < 0.2
    wanted = pose_from_xyzwpr(np.asarray(ns["wanted_xyzwpr"]))
    assert standoff_error_mm(cell, np.asarray(ns["send_for_pose_deg"]), wanted).max() < 0.2


def test_to_part_shapes(calibrated: Calibrated) -> None:
    cal = Calibration.load(calibrated.params)
    q = calibrated.views_deg[:4]
    p = np.random.default_rng(0).normal(0.0, 10.0, (4, 5, 3)) + np.array([0.0, 0.0, 130.0])
    profiles = cal.to_part(q, p)
    assert profiles.shape == (4, 5, 3)
    assert np.allclose(cal.to_part(q, p[:, 2]), profiles[:, 2])
    assert np.allclose(cal.to_part(q[1], p[1]), profiles[1])
    T = cal.model.fk(calibrated.x, q)
    assert np.allclose(profiles[3, 4], T[3, :3, :3] @ p[3, 4] + T[3, :3, 3])
    assert np.allclose(cal.to_part(q[1], p[1, 0]), profiles[1, 0])
    with pytest.raises(ValueError, match="p_sensor_mm: 3 rows of points but q_deg has 4"):
        cal.to_part(q, p[:3, 0])
    with pytest.raises(ValueError, match=r"q_deg: expected shape \(N, 6\)"):
        cal.to_part(q[:, :5], p)


NAN_Q = [10.0, float("nan"), -5.0, 30.0, -60.0, 15.0]


def test_every_api_function_checks_its_arguments_and_names_them(calibrated: Calibrated) -> None:
    """NaN joints gave NaN points or "no inverse kinematics solution", wrong shapes raw numpy
    IndexErrors, and a q_hint_deg with more rows than poses was accepted."""
    cal = Calibration.load(calibrated.params)
    q = calibrated.views_deg[:2]
    xyzwpr = xyzwpr_from_pose(cal.model.fk(cal.model.nominal_x(), q))
    anything: Any = 20  # not what the signature says: checked at run time
    bad_calls: list[tuple[Callable[[], object], type[Exception], str]] = [
        (lambda: cal.to_part([q[0], NAN_Q], [[0, 0, 130]] * 2), ValueError, r"q_deg\[1, 1\] = nan"),
        (lambda: cal.to_part(q, [[0, 0, np.inf]] * 2), ValueError, r"p_sensor_mm\[0, 2\] = inf"),
        (lambda: cal.to_part(q, np.zeros((2, 4, 2))), ValueError, r"p_sensor_mm: expected shape"),
        (lambda: cal.to_part(q, np.zeros(3)), ValueError, r"p_sensor_mm: expected shape"),
        (lambda: cal.to_part(q[0], np.zeros((2, 2, 3))), ValueError, r"p_sensor_mm: expected"),
        (lambda: cal.to_part(q[0], [[0, 0, 1e6]]), ValueError, r"p_sensor_mm\[0, 2\] = 1000000"),
        (lambda: cal.to_part(np.zeros((2, 1, 6)), np.zeros((2, 3))), ValueError, r"q_deg: exp"),
        (lambda: cal.to_part(q, "abc"), ValueError, r"p_sensor_mm: not an array of numbers"),
        (lambda: cal.sensor_pose(NAN_Q), ValueError, r"q_deg\[0, 1\] = nan"),
        (lambda: cal.sensor_pose(np.zeros((0, 6))), ValueError, r"q_deg: .* N >= 1"),
        (lambda: cal.sensor_pose([0, 0, 0, 0, 0, 1e4]), ValueError, r"within \+-720 deg"),
        (lambda: cal.compensate_joints([NAN_Q]), ValueError, r"q_deg\[0, 1\] = nan"),
        (lambda: cal.compensate_joints(q[:, :4]), ValueError, r"q_deg: expected shape"),
        (lambda: cal.compensate_joints(q, settings=anything), TypeError, r"settings: expected"),
        (lambda: cal.compensate_poses(xyzwpr[:, :5]), ValueError, r"xyzwpr: expected shape"),
        (lambda: cal.compensate_poses([[np.nan] * 6]), ValueError, r"xyzwpr\[0, 0\] = nan"),
        (lambda: cal.compensate_poses(xyzwpr, q[[0, 1, 1]]), ValueError, r"q_hint_deg: 3 rows"),
        (lambda: cal.compensate_poses(xyzwpr, q[:1]), ValueError, r"q_hint_deg: 1 rows"),
        (lambda: cal.compensate_poses(xyzwpr, [q[0], NAN_Q]), ValueError, r"q_hint_deg\[1\]"),
        (lambda: cal.compensate_poses(xyzwpr, q[:, :3]), ValueError, r"q_hint_deg: expected"),
        (lambda: command_xyzwpr(anything), TypeError, r"result: expected a Compensation"),
        (lambda: Calibration(cal.model, cal.x[:30]), ValueError, r"x: expected shape \(37,\)"),
        (lambda: Calibration(cal.model, np.full(37, np.nan)), ValueError, r"x\[0\] = nan"),
        (lambda: Calibration.load(anything), TypeError, r"path: expected a file name"),
    ]
    for call, error, message in bad_calls:
        with pytest.raises(error, match=message):
            call()
    # what is right still works: a NaN hint row is "no hint", a single pose takes a (6,) hint
    hints = np.array([q[0], [np.nan] * 6])
    assert cal.compensate_poses(xyzwpr, hints).ok.all()
    assert cal.compensate_poses(xyzwpr[0], q[0]).ok.all()


def test_load_refuses_other_models_and_other_files(calibrated: Calibrated, tmp_path: Path) -> None:
    doc = json.loads(calibrated.params.read_text())
    doc["model"]["version"] = 2
    other = tmp_path / "v2.json"
    other.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"v2\.json: field 'model\.name': .* version 2"):
        Calibration.load(other)
    with pytest.raises(InputError, match="not an rvis parameters file"):
        Calibration.load(write(tmp_path / "x.json", '{"format": "something"}'))
    with pytest.raises(InputError, match="cannot read file"):
        Calibration.load(tmp_path / "missing.json")


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_u95_per_point_propagates_the_identifications_covariance(calibrated: Calibrated) -> None:
    """Task-specific U95: the identification's covariance at each point's pose. Drawn
    parameters from that covariance move >= 95 % of the points by less than their U95, and the
    U95 is not grossly above what they do (the largest eigenvalue: <= 1.4x the 95th
    percentile); a statement the cell makes combines in quadrature; the shapes of `to_part`."""
    cal = Calibration.load(calibrated.params)
    assert cal.covariance is not None
    names, cov = cal.covariance
    q = calibrated.views_deg[:6]
    p = np.random.default_rng(1).normal(0.0, 8.0, (6, 4, 3)) + np.array([0.0, 0.0, 130.0])
    u = cal.u95_mm(q, p)
    assert u.shape == (6, 4) and np.all(u > 0)
    # Monte Carlo: parameters drawn from the covariance, the points they map
    idx = [cal.model.names.index(n) for n in names]
    rng = np.random.default_rng(2)
    draws = rng.multivariate_normal(np.zeros(len(names)), cov, size=400)
    base = cal.to_part(q, p)
    moved = []
    for d in draws:
        x = cal.x.copy()
        x[idx] += d
        moved.append(np.linalg.norm(Calibration(cal.model, x).to_part(q, p) - base, axis=-1))
    m = np.array(moved)  # (400, 6, 4)
    assert np.mean(m <= u) >= 0.95
    assert np.all(u <= 1.4 * np.percentile(m, 95, axis=0) + 1e-4)
    # the cell's statement in quadrature; a nominal calibration states only that
    assert np.allclose(cal.u95_mm(q, p, 0.1), np.hypot(u, 0.1))
    nominal = Calibration.nominal(cal.model)
    assert np.allclose(nominal.u95_mm(q[0], p[0], 0.08), 0.08)
    with pytest.raises(ValueError, match="statement_u95_mm"):
        cal.u95_mm(q, p, -1.0)
