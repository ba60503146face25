"""The compliant model at the application's edges: the parameters JSON records the model
(a file without it is rigid), the measurements CSV carries an optional temp_c column, and
`rvis experiment accuracy` writes its table."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from app.config import CellConfig
from app.errors import InputError
from app.formats.csvfiles import load_dataset
from app.formats.files import write_json, write_measurements, write_targets
from app.formats.params import carried_from_json, from_json, to_json
from app.sim.accuracy import measure_views, plan_views
from app.sim.cell import make_cell
from calib.compliance import CompliantModel, CompliantSettings
from calib.identify import Measurements, identify


@pytest.fixture(scope="module")
def warm(cfg: CellConfig) -> Measurements:
    cell = make_cell(cfg, seed=31)
    rng = np.random.default_rng(31)
    views = plan_views((cell,), cfg.model(), cfg.spheres_part_mm, 10, (20.0, 30.0), rng)
    return measure_views(cell, views).measured


def test_params_json_records_the_compliant_model(
    cfg: CellConfig, warm: Measurements, tmp_path: Path
) -> None:
    settings = CompliantSettings(payload_kg=4.0, reference_temp_c=21.0)
    model = CompliantModel.of(cfg.model(), settings)
    result = identify(model, warm)
    doc = to_json(model, result)
    assert doc["model"]["kind"] == "compliant" and len(doc["parameters"]) == 43
    units = {p["name"]: p["unit"] for p in doc["parameters"]}
    assert units["c2_upper"] == "rad/m" and units["expansion_per_k"] == "1/K"
    write_json(tmp_path / "p.json", doc)
    back, x = from_json(tmp_path / "p.json")
    assert isinstance(back, CompliantModel) and back.settings == settings
    np.testing.assert_array_equal(x, result.x)


def test_a_params_file_without_a_model_kind_is_rigid(cfg: CellConfig, tmp_path: Path) -> None:
    model = cfg.model()
    doc = to_json(model, identify(model, warm_rigid(cfg)))
    assert doc["model"]["kind"] == "rigid" and len(doc["parameters"]) == 37
    del doc["model"]["kind"]
    write_json(tmp_path / "old.json", doc)
    back, x = from_json(tmp_path / "old.json")
    assert back.kind == "rigid" and x.shape == (37,)
    doc["parameters"].append({"name": "c2_upper", "value": 1e-5})
    write_json(tmp_path / "bad.json", doc)
    with pytest.raises(InputError, match=r"parameters\[37\].*unknown parameter 'c2_upper'"):
        from_json(tmp_path / "bad.json")


def test_a_rigid_params_file_is_carried_at_its_calibration_temperature(
    cfg: CellConfig, warm: Measurements, tmp_path: Path
) -> None:
    """A rigid identification's file records the mean temperature of its measurements; carried
    into the compliant model it maps its views' sphere centres where the rigid version does at
    that temperature (1 um). A file written before the field, or one whose measurements had no
    temperature, is carried at the reference temperature; a non-number is refused."""
    rigid = cfg.model()
    compliant = CompliantModel.of(rigid, CompliantSettings(payload_kg=4.0, reference_temp_c=21.0))
    result = identify(rigid, warm)
    doc = to_json(rigid, result)
    assert warm.temp_c is not None
    assert doc["calibration_temp_c"] == pytest.approx(float(np.mean(warm.temp_c)), abs=1e-12)
    t_cal = float(doc["calibration_temp_c"])
    assert abs(t_cal - 21.0) > 2.0  # far enough from the reference to tell them apart
    q, c = warm.q_deg, warm.c_sensor_mm
    p_rigid = rigid.points_part(result.x, q, c)

    def error_mm(path: Path, temp_c: float) -> float:
        model, x = carried_from_json(compliant, path)
        assert model is compliant
        p = model.points_part(x, q, c, temp_c=np.full(len(q), temp_c))
        return float(np.linalg.norm(p - p_rigid, axis=1).max())

    write_json(tmp_path / "p.json", doc)
    assert error_mm(tmp_path / "p.json", t_cal) < 1e-3
    for old in (
        {k: v for k, v in doc.items() if k != "calibration_temp_c"},
        {**doc, "calibration_temp_c": None},
    ):
        write_json(tmp_path / "old.json", old)
        assert error_mm(tmp_path / "old.json", 21.0) < 1e-3
        assert error_mm(tmp_path / "old.json", t_cal) > 0.05
    write_json(tmp_path / "bad.json", {**doc, "calibration_temp_c": "25"})
    with pytest.raises(InputError, match=r"field 'calibration_temp_c': '25' is not a finite"):
        from_json(tmp_path / "bad.json")
    no_temp = identify(rigid, dataclasses.replace(warm, temp_c=None))
    assert to_json(rigid, no_temp)["calibration_temp_c"] is None


def warm_rigid(cfg: CellConfig) -> Measurements:
    cell = make_cell(cfg, seed=32, compliance=False, thermal=False)
    views = plan_views(
        (cell,), cfg.model(), cfg.spheres_part_mm, 6, (20.0, 20.0), np.random.default_rng(32)
    )
    return measure_views(cell, views).measured


def test_measurements_csv_temperature_column(warm: Measurements, tmp_path: Path) -> None:
    targets = {t: p for t, p in zip(warm.targets, warm.p_part_mm, strict=True)}
    write_targets(tmp_path / "t.csv", targets)
    write_measurements(tmp_path / "m.csv", warm.targets, warm.q_deg, warm.c_sensor_mm, warm.temp_c)
    data = load_dataset(tmp_path / "m.csv", tmp_path / "t.csv")
    assert data.temp_c is not None
    np.testing.assert_allclose(data.temp_c, np.asarray(warm.temp_c), atol=1e-6)
    write_measurements(tmp_path / "n.csv", warm.targets, warm.q_deg, warm.c_sensor_mm)
    assert load_dataset(tmp_path / "n.csv", tmp_path / "t.csv").temp_c is None
    lines = (tmp_path / "m.csv").read_text().splitlines()
    lines[3] = lines[3].rsplit(",", 1)[0] + ",250.0"
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"bad.csv:4: field 'temp_c': 250 degC is outside"):
        load_dataset(tmp_path / "bad.csv", tmp_path / "t.csv")


def test_experiment_accuracy_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["experiment", "accuracy", "--seeds", "1", "--validation", "30"]
    assert main([*argv, "--views-per-sphere", "8", "--out", str(tmp_path)]) == 0
    md = (tmp_path / "accuracy.md").read_text()
    rows = {line.split("|")[1].strip(): line for line in md.splitlines() if line.startswith("| ")}
    assert {"rigid", "compliant, no temp", "compliant", "noise floor"} <= set(rows)
    seeds = json.loads((tmp_path / "accuracy-seeds.json").read_text())["seeds"]
    r = seeds[0]["rmse_mm"]
    assert r["compliant"] < r["rigid"] and r["noise floor"] < r["rigid"]
    assert "rvis experiment accuracy: 1 seeds" in capsys.readouterr().out
    assert main(["experiment", "accuracy", "--views-per-sphere", "0"]) == 2


def test_experiment_paper_with_the_compliant_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fast = ["--iterations", "1", "--swarm", "4", "--grid-step", "30", "--search-step", "30"]
    # 100 validation positions: each is a move of the robot, whose repeatability (0.037 mm RMS
    # there) makes the RMSE of 20 too noisy to order two models 5-20 % apart
    argv = ["experiment", "paper", "--seeds", "1", "--validation", "100", "--no-criteria"]
    assert main([*argv, "--compliant", "--workers", "1", "--out", str(tmp_path), *fast]) == 0
    text = capsys.readouterr().out
    assert "Random vs planned, rigid and compliant model" in text
    seed = json.loads((tmp_path / "seeds.json").read_text())["seeds"][0]
    rmse = seed["rmse_mm"]
    assert set(rmse) == {"random", "planned", "random (compliant)", "planned (compliant)"}
    # the simulated cell has gravity compliance: the compliant model explains it
    assert rmse["random (compliant)"] < rmse["random"]
    assert rmse["planned (compliant)"] < rmse["planned"]
    assert "## Rigid and compliant model" in (tmp_path / "experiment.md").read_text()


@pytest.mark.parametrize(
    ("change", "field", "reason"),
    [
        ({"kind": "compliant"}, "model.kind", "'compliant' does not match model.name"),
        ({"kind": "compliant", "compliant": {}}, "model.kind", "does not match model.name"),
        ({"compliant": {"payload_kg": 1.0}}, "model.compliant", "in a rigid one"),
        ({"kind": "flexible"}, "model.kind", "'flexible' does not match"),
    ],
)
def test_a_params_file_whose_model_name_and_kind_disagree_is_refused(
    cfg: CellConfig, tmp_path: Path, change: dict[str, object], field: str, reason: str
) -> None:
    """The rigid model's name with kind "compliant" (and no compliant settings) was read as a
    compliant model with default settings: a silently different model."""
    model = cfg.model()
    doc = to_json(model, identify(model, warm_rigid(cfg)))
    doc["model"] = {**doc["model"], **change}
    write_json(tmp_path / "p.json", doc)
    with pytest.raises(InputError, match=rf"p\.json: field '{field}': .*{reason}"):
        from_json(tmp_path / "p.json")


def test_a_compliant_params_file_needs_every_compliant_setting(
    cfg: CellConfig, warm: Measurements, tmp_path: Path
) -> None:
    model = CompliantModel.of(cfg.model(), CompliantSettings(payload_kg=4.0))
    good = to_json(model, identify(model, warm))
    cases: list[tuple[dict[str, object], str, str]] = [
        ({"kind": "rigid"}, "model.kind", "'rigid' does not match"),
        ({"compliant": None}, "model.compliant", "needs the compliant model's settings"),
        ({"compliant": "yes"}, "model.compliant", "needs the compliant model's settings"),
    ]
    settings = good["model"]["compliant"]
    for key in settings:
        without = {k: v for k, v in settings.items() if k != key}
        cases.append(({"compliant": without}, f"model.compliant.{key}", "missing field"))
    cases += [
        ({"compliant": {**settings, "payload_kg": "4"}}, "model.compliant.payload_kg", "finite"),
        ({"compliant": {**settings, "identify_expansion": 1}}, "model.compliant.identify_", "true"),
        ({"compliant": {**settings, "payload_kg": -1.0}}, "model.compliant", "payload_kg"),
        ({"compliant": {**settings, "colour": "red"}}, "model.compliant", "unknown setting"),
    ]
    for change, field, reason in cases:
        doc = {**good, "model": {**good["model"], **change}}
        write_json(tmp_path / "c.json", doc)
        with pytest.raises(InputError, match=rf"c\.json: field '{field}.*{reason}"):
            from_json(tmp_path / "c.json")
    doc = {**good, "model": {**good["model"]}}
    del doc["model"]["kind"]  # a compliant model's name without its kind: not a rigid model
    write_json(tmp_path / "c.json", doc)
    with pytest.raises(InputError, match=r"'rigid' does not match model\.name"):
        from_json(tmp_path / "c.json")
