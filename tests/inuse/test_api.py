"""The API example of docs/api.md runs as written, and its results match the simulated cell's
true robot; the shapes `to_part` accepts; a parameters file of another model is refused."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.api import Calibration
from app.errors import InputError
from calib.transforms import apply
from calib.wpr import pose_from_xyzwpr
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
    with pytest.raises(ValueError, match="4 configurations but 3 points"):
        cal.to_part(q, p[:3, 0])
    with pytest.raises(ValueError, match="expected joints"):
        cal.to_part(q[:, :5], p)


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
