"""`rvis commission --sim` with every sweep rendered (camera, galvo, the vision pipeline) end to
end, and killed in its calibration step and resumed (issue 30). In a module of its own: the
uninterrupted reference run is a module fixture, and the geometric commissioning tests
(tests/app/test_commission.py) need not wait for it on the same worker."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from app.config import load_cell
from app.line.statedir import StateDir
from app.sim.commission import RENDERED_EDGE_U_MM
from tests.app.test_commission import CELL, ROOT, kill_at
from tests.groups import GIGE_CAMERA

pytestmark = GIGE_CAMERA


#: the shortest rendered commissioning that passes: 12 frames a sweep, 5 configurations a
#: sphere and no random views beyond them (20 calibration views; the pre-calibration the plan
#: is made on measures as many random ones, at least the plan's), one validation view a sphere,
#: 3 workspace positions; the
#: robot repeats exactly (issue 38 item 9): the sensor acceptance's SD takes the robot's motion
#: between its 9 stops as the reference, and the M-710iC/50's repeatability (RP 0.07 mm) puts
#: SD at 0.060 mm against the 0.015 mm limit, a failure of the test's design, not of the sensor
#: (open: an SD reference that no stop error enters)
RENDERED_SHORT = (
    CELL
    + "[sweep]\nn_frames = 12\n[calibration]\nconfigs_per_sphere = 5\n"
    + "[commission]\nvalidation_views = 1\nworkspace_positions = 3\n"
    + "calibration_views_per_sphere = 5\n"
    + "[simulation]\nrepeatability_mm = 0.0\n"
)
RENDERED = ["commission", "--sim", "--yes", "--state-dir"]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The state directory of one uninterrupted rendered commissioning (RENDERED_SHORT), run to
    its end as a process: the reference of the tests below (about 1 min)."""
    folder = tmp_path_factory.mktemp("rendered")
    (folder / "cell.toml").write_text(RENDERED_SHORT)
    state = folder / "state"
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "app", *RENDERED, str(state), "--cell", str(folder / "cell.toml")]
    out = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, (out.stdout + out.stderr)[-3000:]
    return state


@pytest.mark.slow  # its fixture: every sphere measured through rendered sweeps
def test_the_rendered_commissioning_measures_through_camera_and_galvo(rendered: Path) -> None:
    """The sequence with every sweep rendered by the simulated cell and measured by the vision
    pipeline with the sensor calibration of step 3 (RENDERED_SHORT: fewer frames or views made
    it reject too many views, 7 of 24 with fewer calibration targets: it failed)."""
    report = json.loads((StateDir(rendered).commission / "commission.json").read_text())
    assert report["complete"] and all(s["status"] == "passed" for s in report["steps"])
    steps = {s["name"]: s["results"] for s in report["steps"]}
    assert steps["calibration"]["measurements"] >= 18 and steps["calibration"]["rms_mm"] < 0.1
    assert steps["validation"]["rmse_mm"] < 0.1 and steps["validation"]["true_rmse_mm"] < 0.2
    assert "not applicable" not in str(steps["acceptance"])  # images: the acceptance ran
    ws = steps["workspace"]
    assert ws["measured"] == ws["positions"] == 3 and ws["true_rmse_mm"] < 0.2
    # the rendered sensor's edge allowances (bench/edge.py, certified bores and slots) in the
    # cell file the service reads, where larger than the geometric rule's 0.002 mm
    cell = load_cell(StateDir(rendered).cell)
    assert cell.sensor.edge_u_mm == max(0.002, RENDERED_EDGE_U_MM["hole"])
    assert cell.sensor.edge_u_slot_mm == RENDERED_EDGE_U_MM["slot"] > 0.002


@pytest.mark.slow  # about 1.5 min: a rendered commissioning killed in its calibration, resumed
def test_a_rendered_commissioning_killed_in_its_calibration_resumes_with_the_same_views(
    rendered: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Killed (kill -9) in the middle of its calibration step, a rendered commissioning run
    again measures the very images an uninterrupted run (the fixture's) measures there (the
    simulated camera's noise belongs to the frame, not to how many frames came before: issue
    30, where a resumed run rejected 3 views where an uninterrupted one rejected 2, every rerun
    the same 3), and passes. bench/commission_resume.py kills it at three points of the step."""
    cell = tmp_path / "cell.toml"
    cell.write_text(RENDERED_SHORT)
    reference, killed = rendered, tmp_path / "killed"
    # the sensor calibrated from the reference's recorded targets (the same images, not
    # rendered again: 8 s of a loaded worker), as an engineer gives them with --sensor-data
    recorded = StateDir(reference).commission / "sensor-data"
    argv = [*RENDERED[:-1], "--cell", str(cell), "--sensor-data", str(recorded), "--state-dir"]
    kill_at([*argv, str(killed)], "to calibration view 10/20 ", 600)
    journal = json.loads((StateDir(killed).commission / "journal.json").read_text())
    assert journal["steps"][-1]["name"] == "calibration"
    assert journal["steps"][-1]["status"] == "started"

    assert main([*argv, str(killed)]) == 0, capsys.readouterr().out[-3000:]
    got, ref = _measured(killed), _measured(reference)
    # the same views, none rejected more: the same spheres, the same joints (the plan is made
    # on the pre-calibration, whose sensor calibrated from the same recorded targets agrees to
    # its last bits: the joints to 1e-6 deg)
    assert [r[0] for r in got] == [r[0] for r in ref]
    q_got, q_ref = (np.array([r[1:7] for r in rows], float) for rows in (got, ref))
    np.testing.assert_allclose(q_got, q_ref, rtol=0, atol=1e-5)
    # the same images: the centres agree to the vision's last bits (different image noise, as
    # before the fix, moved them by up to 3.6 um: bench/commission_resume.py)
    diff = np.abs(np.array([r[7:] for r in got], float) - np.array([r[7:] for r in ref], float))
    assert diff.max() <= 1e-4
    report = json.loads((StateDir(killed).commission / "commission.json").read_text())
    steps = {s["name"]: s for s in report["steps"]}
    assert [e["status"] for e in steps["calibration"]["earlier"]] == ["interrupted"]
    ref_journal = json.loads((StateDir(reference).commission / "journal.json").read_text())
    ref_cal = next(s for s in ref_journal["steps"] if s["name"] == "calibration")["results"]
    cal = steps["calibration"]["results"]
    assert cal["rejected"] == ref_cal["rejected"]
    assert cal["rms_mm"] == pytest.approx(ref_cal["rms_mm"], abs=1e-6)
    assert all(s["status"] == "passed" for s in report["steps"])


def _measured(state: Path) -> list[list[str]]:
    """The calibration step's measurements (target, joints, centre, temperature) as text."""
    text = (StateDir(state).commission / "calibration_measurements.csv").read_text()
    return [line.split(",") for line in text.splitlines()[1:]]
