"""`rvis plan`: the plan file, reproducibility over processes, and its bad inputs (exit 2)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from app.config import CellConfig
from app.formats.files import write_json
from app.formats.params import from_json, to_json
from app.planning import read_plan
from calib.identify import identify
from calib.transforms import apply, inverse
from tests.conftest import simulated

FAST = ["--iterations", "1", "--swarm", "4", "--grid-step", "30", "--search-step", "30"]


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_plan_writes_a_plan_and_is_the_same_on_two_processes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    one, two = tmp_path / "one.json", tmp_path / "two.json"
    code, out, err = run(["plan", "--out", str(one), "--workers", "1", *FAST], capsys)
    assert code == 0, err
    assert "random, same positions" in out and "place P4" in err  # table and progress
    code, _, err = run(["plan", "--out", str(two), "--workers", "2", *FAST], capsys)
    assert code == 0, err
    positions, qs, cs = read_plan(one)
    positions2, qs2, _ = read_plan(two)
    assert list(positions) == ["P1", "P2", "P3", "P4"]
    for name in positions:
        assert qs[name].shape == (6, 6) and cs[name].shape == (6, 3)
        assert np.allclose(positions[name], positions2[name]) and np.allclose(qs[name], qs2[name])
    doc = json.loads(one.read_text())
    assert doc["observability"]["rank"] == 30
    assert doc["observability"]["O1"] > doc["random_plan"]["O1"]


def test_fixed_placement_keeps_the_cell_positions(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "plan.json"
    code, text, _ = run(
        ["plan", "--out", str(out), "--placement", "fixed", "--json", *FAST], capsys
    )
    assert code == 0
    base = {s["name"]: s["position_base_mm"] for s in json.loads(text)["spheres"]}
    assert np.allclose(base["P1"], [-647.14, 1254.27, -289.37])


def _cell(tmp_path: Path, text: str) -> str:
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    ("argv", "cell", "message"),
    [
        (["--criterion", "O9"], None, "field '--criterion': unknown criterion 'O9'"),
        (["--iterations", "0"], None, "field '--iterations': must be >= 1"),
        (
            [],
            '[planning]\ncriterion = "O7"\n',
            "cell.toml:2: [planning] criterion: expected one of O1",
        ),
        ([], "[planning]\nmax_tilt_deg = 120.0\n", "[planning] max_tilt_deg: must be <= 90"),
        (
            [],
            "[planning]\nworkspace_mm = [-600.0, 600.0, -600.0, 600.0]\n",
            "feasible region for the spheres is empty",
        ),
        (
            ["--placement", "fixed"],
            '[spheres]\nframe = "base"\n[spheres.positions_mm]\nP1 = [3500.0, 0.0, 0.0]\n',
            "sphere P1: sphere at",
        ),
    ],
)
def test_bad_plan_inputs_exit_2(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    cell: str | None,
    message: str,
) -> None:
    cell_args = ["--cell", _cell(tmp_path, cell)] if cell else []
    code, _, err = run(
        ["plan", "--out", str(tmp_path / "p.json"), *FAST, *cell_args, *argv], capsys
    )
    assert code == 2
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_experiment_paper_writes_table_and_figure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "exp"
    code, text, err = run(
        ["experiment", "paper", "--seeds", "1", "--validation", "20", "--no-criteria",
         "--out", str(out), "--workers", "1", *FAST],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    assert "validation RMSE reduction, median" in text and "18.6 %" in text
    seeds = json.loads((out / "seeds.json").read_text())["seeds"]
    assert len(seeds) == 1 and seeds[0]["n_measurements"] == {"random": 24, "planned": 24}
    assert seeds[0]["o1"]["planned"] > seeds[0]["o1"]["random"]
    assert (out / "fig11.png").stat().st_size > 10_000 and (out / "experiment.md").exists()
    code, _, err = run(["experiment", "paper", "--seeds", "0"], capsys)
    assert code == 2 and "--seeds" in err


def test_plan_on_pre_calibrated_parameters(
    cfg: CellConfig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--params: the plan's configurations are refined on the identified parameters, so the
    sphere appears where planned on that model (and not on the nominal one)."""
    cal, _ = simulated(0)
    result = identify(cfg.model(), cal.measurements)
    params = tmp_path / "params.json"
    write_json(params, to_json(cfg.model(), result))
    out = tmp_path / "plan.json"
    code, _, err = run(
        ["plan", "--params", str(params), "--out", str(out), "--placement", "fixed", *FAST],
        capsys,
    )
    assert code == 0, err
    model, x = from_json(params)
    positions, qs, cs = read_plan(out)
    for name, p in positions.items():
        c_model = apply(inverse(model.fk(x, qs[name])), p)
        assert np.abs(c_model - cs[name]).max() < 1e-6
        c_nominal = apply(inverse(model.fk(model.nominal_x(), qs[name])), p)
        assert np.abs(c_nominal - cs[name]).max() > 0.1


def test_plan_is_made_for_the_cells_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`[calibration] model = "compliant"`: the plan is made for the compliant model's
    parameters (the paper's 30 and the arm compliance), not the rigid model's."""
    cell = tmp_path / "cell.toml"
    cell.write_text('[calibration]\nmodel = "compliant"\n')
    out = tmp_path / "plan.json"
    argv = ["plan", "--out", str(out), "--cell", str(cell), "--placement", "fixed", *FAST]
    code, text, err = run(argv, capsys)
    assert code == 0, err
    assert "for the compliant model (33 parameters)" in text
    doc = json.loads(out.read_text())
    assert doc["settings"]["parameters"][-3:] == ["c2_upper", "c2_fore", "c3_fore"]
    assert doc["observability"]["rank"] == 33
