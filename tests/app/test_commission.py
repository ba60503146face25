"""`rvis commission --sim` end to end on the simulated line (geometric measurements, a 15 deg
planning grid to keep it short): killed in the middle of the first calibration, run again it
continues there; a step that fails its check stops the sequence (exit 3) and runs again next
time; the state directory it leaves is what `rvis run` needs, and the service runs on it with
the commissioned parameters."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from app.config import load_cell
from app.formats.params import from_json
from app.line.params_store import ParamsStore
from app.line.statedir import StateDir
from app.line.store import Store
from tests.groups import GIGE_CAMERA

pytestmark = GIGE_CAMERA

ROOT = Path(__file__).resolve().parents[2]
CELL = "[planning]\ngrid_step_deg = 15.0\n"
STRICT = "[commission]\nmax_validation_rmse_mm = 0.001\n"
TOLERANCE = "[commission]\ntolerance_mm = 1.0\n"  # a body tolerance of +-0.5 mm


SEED = 9  # not the cell file's [simulation] seed (0): the directory must keep it


def _commission(cell: Path, state: Path) -> list[str]:
    return ["commission", "--sim", "--geometric", "--seed", str(SEED), "--yes", "--cell",
            str(cell), "--state-dir", str(state)]  # fmt: skip


def kill_at(argv: list[str], marker: str, timeout_s: float = 600.0) -> list[str]:
    """Run rvis in a child process until `marker` appears in its output (waited for with a
    timeout, no sleep), then SIGKILL it; the lines it printed."""
    import queue
    import threading
    import time

    env = os.environ | {"PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
    lines: list[str] = []
    out: queue.Queue[str | None] = queue.Queue()
    with subprocess.Popen(
        [sys.executable, "-m", "app", *argv], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True,
    ) as child:  # fmt: skip
        assert child.stdout is not None
        stream = child.stdout

        def read() -> None:
            for line in stream:
                out.put(line)
            out.put(None)

        threading.Thread(target=read, daemon=True).start()
        deadline = time.monotonic() + timeout_s
        try:
            while (left := deadline - time.monotonic()) > 0:
                line = out.get(timeout=left)
                if line is None:
                    break
                lines.append(line)
                if marker in line:
                    child.send_signal(signal.SIGKILL)
                    break
            child.wait(timeout=60)
        finally:
            if child.poll() is None:
                child.kill()
    assert any(marker in line for line in lines), "".join(lines[-20:])
    assert child.returncode == -signal.SIGKILL
    return lines


@pytest.mark.slow
def test_commissioning_resumes_after_a_kill_and_leaves_a_cell_ready_to_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cell, state = tmp_path / "cell.toml", tmp_path / "state"
    paths = StateDir(state)
    cell.write_text(CELL)
    kill_at(_commission(cell, state), "to calibration view 3/24")
    journal = json.loads((paths.commission / "journal.json").read_text())
    first = {s["name"]: s for s in journal["steps"] if s["status"] == "passed"}
    assert list(first) == ["devices", "stripe", "sensor", "spheres", "precalibration", "plan"]
    assert journal["steps"][-1]["name"] == "calibration"
    assert journal["steps"][-1]["status"] == "started"  # found so next time: interrupted
    assert not paths.current.exists()

    cell.write_text(CELL + STRICT)  # the same cell file, a validation limit nothing can meet
    assert main(_commission(cell, state)) == 3
    out = capsys.readouterr().out
    for i, name in enumerate(first, start=1):
        assert f"step {i}/11 {name}: passed earlier" in out
    assert "step 7/11 calibration: passed" in out and "step 9/11 validation: failed" in out
    assert "FAIL validation RMSE" in out and "step 10/11" not in out
    report = json.loads((paths.commission / "commission.json").read_text())
    assert report["next_step"] == "validation" and not report["complete"]
    steps = {s["name"]: s for s in report["steps"]}
    assert steps["devices"]["started_utc"] == first["devices"]["started_utc"]  # not run again

    cell.write_text(CELL + TOLERANCE)
    assert main(_commission(cell, state)) == 0
    out = capsys.readouterr().out
    assert "step 7/11 calibration: passed earlier" in out and "step 11/11 ready: passed" in out
    report = json.loads((paths.commission / "commission.json").read_text())
    # the acceptance cannot run on the geometric path: said so, not counted as passed
    statuses = {s["name"]: s["status"] for s in report["steps"]}
    assert report["complete"] and statuses.pop("acceptance") == "not run"
    assert all(status == "passed" for status in statuses.values())
    md = (paths.commission / "commission.md").read_text()  # each step that ran again says so
    started = journal["steps"][-1]["started_utc"]
    assert f"Run 2 times: interrupted (started {started}), then passed." in md
    assert "failed validation RMSE), then passed." in md
    steps = {s["name"]: s for s in report["steps"]}
    validation = steps["validation"]["results"]
    assert validation["rmse_mm"] < 0.1 < 1.0 < validation["rmse_nominal_mm"]
    assert validation["true_rmse_mm"] < 0.1  # against the simulated cell's truth
    # the paper's validation: the validation sphere at 20 workspace positions, the tracker
    # against rvis; it sees what the end-to-end truth sees (the quick check cannot)
    ws = steps["workspace"]["results"]
    assert ws["measured"] == ws["positions"] == 20
    assert 0.8 < ws["rmse_mm"] / ws["true_rmse_mm"] < 1.4  # + the tracker's and sensor's noise
    lo, hi = ws["rmse_95_interval_mm"]
    stated = {c["name"].split(" (")[0]: c for c in steps["workspace"]["checks"] if not c["limit"]}
    mean, largest = stated["workspace error, mean"], stated["workspace error, largest"]
    assert lo < ws["rmse_mm"] < hi and mean["value"] <= ws["rmse_mm"] <= largest["value"]
    assert mean["unit"] == "mm" and "workspace error, 95th percentile" in stated
    # the commissioned cell's U95 of a point (from the 20 end-to-end errors): above the true
    # RMS at the truth's 100 positions, not grossly (1.6x for many errors, more for 20), and
    # VDA 5's ratio against the tolerance, whose limit the state directory's service takes
    assert ws["true_rmse_mm"] < ws["u95_mm"] < 3.0 * ws["true_rmse_mm"]
    assert ws["vda5_ratio"] == pytest.approx(2.0 * ws["u95_mm"] / 1.0)
    # the limit: VDA 5's 0.15 mm for T = 1.0 mm, or 1.5x the cell's own U95 when that is higher
    # (a healthy cell is not at its limit), and the reason with it
    assert ws["accuracy_limit_mm"] == pytest.approx(max(0.15, 1.5 * ws["u95_mm"]))
    assert ("VDA 5" in ws["accuracy_limit_basis"]) and (
        "own U95" in ws["accuracy_limit_basis"]
    ) == (1.5 * ws["u95_mm"] > 0.15)
    md = (paths.commission / "commission.md").read_text()
    assert f"| VDA 5 capability 2 U95 / T ({2 * ws['u95_mm']:.4f} mm / 1.0000 mm) |" in md
    # issue 40 item 5: ratios as ratios, the spheres' x, y, z in columns, the workspace error's
    # figures in the checks table at the RMSE's precision, the steps run again in the heading
    plan = steps["plan"]["results"]
    o1 = f"{plan['planned']['O1']:.4f} / {plan['random']['O1']:.4f}"
    assert f"| O1, planned / random ({o1}) | " in md and " | >= 1.0000 | yes |" in md
    assert "| validation RMSE, calibrated / nominal (" in md and " | <= 1.0000 | yes |" in md
    assert "| name | x_mm | y_mm | z_mm | rms_mm | offset_mm |" in md
    assert f"| workspace error, mean | {mean['value']:.4f} mm | - | - |" in md
    assert (
        "Run again: calibration (after 1 interrupted run), validation (after 1 failed run)." in md
    )
    assert steps["acceptance"]["results"]["not_run"].startswith("geometric path")  # no images
    # the paper's order: a pre-calibration from 30 random views a sphere, the plan made on its
    # parameters (each planned view sees its sphere: none rejected), the first calibration
    # from the plan's 24 views and those random ones, up to 36 a sphere
    pre = steps["precalibration"]["results"]
    assert pre["measurements"] + len(pre["rejected"]) == 120 and "passed" in pre["gates"]
    assert plan["planned_on"] == "the pre-calibration's parameters"
    assert steps["calibration"]["results"]["rejected"] == []
    assert steps["calibration"]["results"]["measurements"] == 24 + pre["measurements"] == 144
    # the simulated PLC writes the cell temperature, and the commissioning cell says so: each
    # measurement carries it (a PLC that does not would give none, never 0 degC)
    rows = (paths.commission / "calibration_measurements.csv").read_text().splitlines()
    assert rows[0].endswith(",temp_c") and len(rows) == 145
    temps = [float(r.rsplit(",", 1)[1]) for r in rows[1:]]
    assert all(15.0 < t < 30.0 for t in temps)
    md = (paths.commission / "commission.md").read_text()
    assert "**10 of 11 steps passed, 1 not run (acceptance)**" in md and "| validation RMSE |" in md
    assert "| 8 | acceptance | not run: geometric path" in md
    # the headline, before the steps: the cell's U95 with what it is, the limit in force (as
    # the ready step wrote it), VDA 5's ratio against the tolerance read as its full range
    head = md.split("| # | step |")[0]
    assert f"**U95 {ws['u95_mm']:.4f} mm**: the expanded uncertainty (95 %) of a point" in head
    limit = load_cell(paths.cell).service.accuracy_limit_mm
    assert f"**Limit the service holds it to: {limit:.4f} mm**" in head
    assert f"**VDA 5 capability 2 U95 / T: {100 * ws['vda5_ratio']:.1f} %**" in head
    assert "T = 1 mm, the full range of the features' tolerance (+-0.5 mm" in head
    assert report["headline"]["accuracy_limit_mm"] == limit

    # the state directory, read the way the service reads it
    cfg = load_cell(paths.cell)
    assert set(cfg.spheres_part_mm) == {"P1", "P2", "P3", "P4"} and cfg.spheres.frame == "part"
    assert cfg.line.plc_temperature  # the simulated line's PLC provides it
    assert cfg.service.accuracy_limit_mm == pytest.approx(ws["accuracy_limit_mm"])
    # the simulated cell it was commissioned on, and how it was measured (issue 40 item 3)
    assert cfg.simulation.seed == SEED and cfg.simulation.geometric
    # the first version carries its workspace validation: the service's first U95 rests on it
    validation = ParamsStore(state).current_document()["validation"]  # type: ignore[index]
    assert len(validation["errors_mm"]) == ws["measured"]
    # to the CSV's digits
    assert max(validation["errors_mm"]) == pytest.approx(largest["value"], abs=1e-6)
    version, _, x = ParamsStore(state).current()  # type: ignore[misc]
    assert version == 1 and paths.plan.is_file() and paths.sensor.is_file()
    np.testing.assert_array_equal(x, from_json(paths.commission / "params.json")[1])
    store = Store(paths.db, read_only=True)
    assert [a["source"] for a in store.applied()] == ["commissioning"]
    store.close()
    assert main(_commission(cell, state)) == 0  # all done: nothing runs again
    assert "commissioned already" in capsys.readouterr().out

    # the command the commissioning prints: the state directory supplies the cell file, the
    # plan and the sensor, and the line measures as it was commissioned (geometric)
    run = shlex.split(steps["ready"]["results"]["run"])
    assert run[:3] == ["rvis", "run", "--sim"] and "--geometric" in run
    assert "--cell" not in run and "--plan" not in run
    assert main([*run[1:], "--windows", "2", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["measurements"] == 2 and summary["true_rmse_start_mm"] < 0.1
    assert ParamsStore(state).current_version() == 1  # it started from the commissioning
    # the directory alone runs its own cell, measured as commissioned (no --seed, --geometric);
    # another seed is another cell: one line, exit 2
    alone = ["run", "--sim", "--windows", "1", "--json", "--state-dir", str(state)]
    assert main(alone) == 0
    assert json.loads(capsys.readouterr().out)["true_rmse_start_mm"] < 0.1
    assert main([*alone, "--seed", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "cell.toml" in err and "seed 9" in err and len(err.splitlines()) == 1


def test_the_engineer_stops_it_and_a_journal_of_another_set_up_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import io

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    cell, state = tmp_path / "cell.toml", tmp_path / "state"
    cell.write_text(CELL)
    argv = ["commission", "--sim", "--geometric", "--cell", str(cell), "--state-dir", str(state)]
    monkeypatch.setattr(sys, "stdin", Terminal("y\nn\n"))  # start step 1, not step 2
    assert main(argv) == 1
    out = capsys.readouterr().out
    assert "step 1/11 devices: passed" in out and "stopped: not confirmed" in out
    report = json.loads((StateDir(state).commission / "commission.json").read_text())
    assert report["next_step"] == "stripe"

    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # not a terminal, no --yes
    assert main(argv) == 2
    assert "needs a terminal (or --yes)" in capsys.readouterr().err
    assert main([*argv, "--yes", "--seed", "7"]) == 2  # another simulated cell
    err = capsys.readouterr().err.strip()
    assert "journal.json: this commissioning was started with" in err and "--restart" in err
    assert len(err.splitlines()) == 1
