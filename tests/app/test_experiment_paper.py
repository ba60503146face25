"""`rvis experiment paper`: resuming from seeds.json, planning for the compliant model."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.commands.cli import main
from app.config import CellConfig, load_cell
from app.errors import InputError
from app.planning import plan_settings, run_plan
from app.sim.paper import run_seed
from calib.compliance import ARM_COMPLIANCE, select_model
from calib.model import PAPER_30

FAST = ["--iterations", "1", "--swarm", "4", "--grid-step", "30", "--search-step", "30"]
BASE = ["experiment", "paper", "--validation", "20", "--no-criteria", "--workers", "1", *FAST]
FAST_PLAN: dict[str, Any] = {
    "iterations": 1,
    "swarm_size": 4,
    "grid_step_deg": 30.0,
    "search_step_deg": 30.0,
}


def _seeds(out: Path) -> dict[int, dict[str, object]]:
    return {d["seed"]: d for d in json.loads((out / "seeds.json").read_text())["seeds"]}


def test_resume_keeps_the_seeds_done_and_runs_the_others_as_a_fresh_run_would(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main([*BASE, "--seeds", "1", "--out", str(out)]) == 0
    first = _seeds(out)
    assert list(first) == [0]
    assert main([*BASE, "--seeds", "2", "--out", str(out), "--resume"]) == 0
    log = capsys.readouterr().out
    assert "seed 0 (1/2): from" in log and "seed 1 (2/2): O1" in log
    both = _seeds(out)
    assert list(both) == [0, 1]
    assert both[0] == first[0]  # taken over unchanged, not run again
    fresh = run_seed(load_cell(None), 1, 20, False, workers=1, **FAST_PLAN)
    assert both[1]["rmse_mm"] == pytest.approx(fresh.rmse_mm, rel=1e-9)
    md = (out / "experiment.md").read_text()
    assert "2 seeds (0..1)" in md and "load average" in md


def test_resume_refuses_a_file_of_other_settings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main([*BASE, "--seeds", "1", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main([*BASE, "--seeds", "1", "--out", str(out), "--resume", "--compliant"]) == 2
    err = capsys.readouterr().err
    assert "seeds.json" in err and "settings" in err
    assert main([*BASE, "--seeds", "1", "--resume"]) == 2
    assert "--resume" in capsys.readouterr().err


def test_a_plan_for_the_compliant_model_determines_its_compliance_better(
    cfg: CellConfig,
) -> None:
    """Planned for the compliant model (its 30 + 3 arm compliance parameters), the
    configurations determine the compliance coefficients better (smaller predicted standard
    deviations from the compliant model's information matrix) than the rigid plan's."""
    rigid = cfg.model()
    compliant = select_model("compliant", rigid)
    xc = compliant.nominal_x()
    active = compliant.default_active()
    assert active == (*PAPER_30, *ARM_COMPLIANCE)
    fast: dict[str, Any] = {"placement": "fixed", "grid_step_deg": 20.0, "workers": 1}
    plans = {
        "rigid": run_plan(cfg, rigid, rigid.nominal_x(), **fast),
        "compliant": run_plan(cfg, compliant, xc, **fast),
    }
    assert plans["rigid"].settings.active == PAPER_30
    assert plans["compliant"].settings.active == active
    std = {}
    for name, plan in plans.items():
        q = np.concatenate([sp.q_deg for sp in plan.spheres])
        c = np.concatenate([sp.c_sensor_mm for sp in plan.spheres])
        J = compliant.point_jacobian(xc, q, c, active)
        cov = np.linalg.inv(np.einsum("kil,kim->lm", J, J))
        std[name] = np.sqrt(np.diag(cov)[-3:])
    assert np.all(std["compliant"] < std["rigid"])
    assert plans["compliant"].observability.rank == 33


def test_planning_section_reads_revisits_and_the_workspace_criterion(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[planning]\ncriterion = "I"\nrevisits = 2\n')
    settings, _ = plan_settings(load_cell(cell))
    assert (settings.criterion, settings.revisits) == ("I", 2)
    cell.write_text("[planning]\nrevisits = 11\n")
    with pytest.raises(InputError, match=r"cell.toml:2: \[planning\] revisits: must be <= 10"):
        load_cell(cell)


def _fake_run(folder: Path, planned: list[float]) -> None:
    """seeds.json of a run whose random RMSE is 0.05 mm (0.04 vs the truth: 0.03 noise)."""
    seeds = [
        {
            "seed": k,
            "rmse_mm": {"random": 0.05, "planned": p},
            "rmse_truth_mm": {"random": 0.04, "planned": 0.02},
        }
        for k, p in enumerate(planned)
    ]
    folder.mkdir()
    (folder / "seeds.json").write_text(json.dumps({"seeds": seeds}))


def test_paper_compare_pairs_the_seeds_of_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _fake_run(tmp_path / "a", [0.04, 0.045, 0.055])
    _fake_run(tmp_path / "b", [0.036, 0.045, 0.05, 0.01])  # one more seed: left out
    argv = ["experiment", "paper-compare", "--runs", f"base={tmp_path / 'a'}", str(tmp_path / "b")]
    assert main(argv) == 0
    rows = [r.split(" | ") for r in capsys.readouterr().out.splitlines()[2:]]
    assert [r[0].strip("| ") for r in rows] == ["base", str(tmp_path / "b")]
    base, other = rows
    assert base[4] == "10.0 %" and base[7] == "2/3" and base[8] == "50.0 %"
    assert base[5] == "-10.0 .. 20.0 %"  # the median of 3 resampled values: their range
    assert base[9] == "40.0 %"  # 1 - 0.03 / 0.05: the validation noise stays
    assert other[2] == "3" and other[4] == "10.0 %" and other[7] == "2/3"
    assert other[10].startswith("-9.1 %, 2/3")  # median of -10 %, 0 %, -9.1 %
    with pytest.raises(SystemExit) as missing:  # --runs is required: a usage error
        main(["experiment", "paper-compare"])
    assert missing.value.code == 2
