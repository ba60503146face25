"""What the commissioning report says first (issue 51 item 2): the cell's U95 with what it is,
the limit the service will hold it to and its basis, VDA 5's ratio or why none is stated, the
tolerance as the full range (+-0.5 mm is 1.0) and a value that may be a half-range questioned;
a step that did not run (the acceptance on the geometric path) said so and not counted as
passed; the acceptance saying how it departs from VDI/VDE 2634-2, with a legend for PF, PS
and SD and the frame of its positions."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from app.commission.acceptance import LEGEND, METHOD, verify
from app.commission.checks import MM, StepResult, at_most, holds, ratio_at_most
from app.commission.journal import NOT_RUN, PASSED, Journal, StepRecord
from app.commission.report import counts_text, markdown, to_json
from app.commission.sequence import run_sequence
from app.commission.table import COMMISSIONING, CommissionStep, Procedure
from app.commission.workspace import accuracy_results
from app.config import load_cell
from app.line.measure import GeometricSensor

SETUP = {"cell": "cell.toml", "sim": True}
STARTED = "2026-11-25T06:00:00+00:00"


def _finish(journal: Journal, name: str, *checks: Any, **results: Any) -> None:
    journal.finish(StepRecord(name, PASSED, STARTED, 1.5, checks, results, ()))


def _workspace(journal: Journal, u95: float, tolerance_mm: float, **more: Any) -> None:
    results = {
        "positions": 20,
        "measured": 20,
        "views": 20,
        "rmse_mm": 0.0387,
        "rmse_95_interval_mm": [0.0332, 0.0436],
        "rejected": [],
        **accuracy_results(u95, tolerance_mm),
        **more,
    }
    checks = [at_most("workspace RMSE", 0.0387, 0.2, "mm", fmt=MM)]
    if tolerance_mm > 0:
        checks.append(ratio_at_most("VDA 5 capability 2 U95 / T", 2 * u95, tolerance_mm, 0.3, "mm"))
    status = PASSED if all(c.ok for c in checks) else "failed"
    journal.finish(StepRecord("workspace", status, STARTED, 90.0, tuple(checks), results, ()))


def test_the_headline_states_u95_with_what_it_is_its_limit_and_vda5_first(
    tmp_path: Path,
) -> None:
    journal = Journal(tmp_path, SETUP)
    for name in ("devices", "stripe", "sensor", "spheres", "precalibration", "plan", "calibration"):
        _finish(journal, name, holds(f"{name} ok", True))
    _workspace(journal, 0.0812, 1.0, true_rmse_mm=0.0423)
    _finish(journal, "ready", holds("cell.toml reads back", True), accuracy_limit_mm=0.15)
    md = markdown(journal)
    head = md.split("| # | step |")[0]  # before the steps' table: the first page
    assert "## Headline" in head
    assert "**U95 0.0812 mm**: the expanded uncertainty (95 %) of a point measured now, 3-D" in head
    assert "the accuracy statement the in-line service starts from" in head
    assert "**Limit the service holds it to: 0.1500 mm** (`[service] accuracy_limit_mm`)" in head
    assert "VDA 5 (2 U95 / T <= 30 %) for a tolerance of 1 mm" in head  # its basis
    assert "**VDA 5 capability 2 U95 / T: 16.2 %** (at most 30 %)" in head
    assert "T = 1 mm, the full range of the features' tolerance (+-0.5 mm; +-0.5 mm is 1.0)" in head
    assert "Workspace RMSE 0.0387 mm (95 % interval 0.0332-0.0436 mm) at 20 of 20 positions" in head
    assert "WARNING" not in md
    assert "- rejected: none\n" in md  # an empty list said so (was "- rejected: ")
    h = to_json(journal)["headline"]
    assert h["u95_mm"] == 0.0812 and h["accuracy_limit_mm"] == 0.15
    assert h["vda5_ratio"] == 2 * 0.0812 / 1.0 and "3-D" in h["u95_what"]


def test_a_tolerance_that_may_be_a_half_range_is_questioned(tmp_path: Path) -> None:
    """The rule: questioned whenever the cell's U95 fails VDA 5 against tolerance_mm read as
    the full range (2 U95 / T > 30 %), saying what the ratio would be at twice the value."""
    journal = Journal(tmp_path, SETUP)
    _workspace(journal, 0.1, 0.5)  # +-0.5 mm entered as 0.5: 2 U95 / T = 40 %
    md = markdown(journal)
    assert (
        "**WARNING: check tolerance_mm: 0.5 mm is read as the full range T (+-0.25 mm), and the"
        " cell's U95 0.1000 mm fails VDA 5 against it (2 U95 / T = 40 % > 30 %); if the"
        " features' tolerance is +-0.5 mm, set tolerance_mm = 1 (2 U95 / T = 20 %: would"
        " pass).**" in md.split("| # | step |")[0]
    )
    assert "tolerance_question" in to_json(journal)["headline"]
    journal = Journal(tmp_path / "ok", SETUP)
    _workspace(journal, 0.1, 1.0)  # 20 %: passes, not questioned
    assert "WARNING" not in markdown(journal)


def test_without_a_tolerance_the_report_says_why_no_vda5_ratio(tmp_path: Path) -> None:
    journal = Journal(tmp_path, SETUP)
    _workspace(journal, 0.08, 0.0)
    head = markdown(journal).split("| # | step |")[0]
    assert (
        "- **VDA 5 capability: not stated**: no tolerance given ([commission] tolerance_mm: the"
        " full range of the features' tolerance, +-0.5 mm is 1.0); the limit assumes T = 1 mm"
        " (+-0.5 mm).\n" in head
    )
    # the limit the ready step writes without a tolerance: VDA 5's for T = 1 mm, or 1.5x the
    # cell's own U95 when that is higher (calib.uncertainty.accuracy_limit_mm)
    assert "**Limit the service holds it to: 0.1500 mm**" in head
    journal = Journal(tmp_path / "high", SETUP)
    _workspace(journal, 0.12, 0.0)
    assert "**Limit the service holds it to: 0.1800 mm**" in markdown(journal)
    assert "1.5 x the cell's own U95 0.120 mm" in markdown(journal)


def _acceptance_on_the_geometric_path(ctx: Any) -> StepResult:
    """The commissioning's acceptance step as it runs on the simulated line's geometric path
    (the calibrated model stood in for by the nominal one)."""
    return verify(ctx, ctx.cell().model().nominal_x(), None)  # type: ignore[arg-type]


def test_a_step_that_did_not_run_says_so_and_is_not_counted_as_passed(tmp_path: Path) -> None:
    """`rvis commission --sim --geometric` showed the acceptance "passed 0/0" and "10 of 10
    steps passed": it cannot measure PF, PS or SD without images."""
    cfg = load_cell(None)
    said: list[str] = []
    ctx = SimpleNamespace(
        cell=lambda: cfg,
        sphere_sensor=lambda model: GeometricSensor(lambda target: np.zeros(3)),
        say=said.append,
        ask=lambda question: None,
        truth=None,
        robot_s=0.0,
    )
    steps = (
        CommissionStep("devices", "Devices answer", lambda c: StepResult([holds("ok", True)])),
        CommissionStep("acceptance", "Sensor acceptance", _acceptance_on_the_geometric_path),
        CommissionStep("ready", "Ready", lambda c: StepResult([holds("ok", True)])),
    )
    proc = Procedure(steps, "Report", "r.md", "r.json", "done", "rvis-test/1")
    journal = Journal(tmp_path, SETUP, proc)
    assert run_sequence(ctx, journal) is None  # type: ignore[arg-type]
    assert journal.steps["acceptance"].status == NOT_RUN
    assert journal.next_step() is None  # it does not hold the procedure up
    assert "step 2/3 acceptance: not run: geometric path: the simulated sensor" in "\n".join(said)
    md = markdown(journal)
    assert "**2 of 3 steps passed, 1 not run (acceptance)**; done." in md
    assert (
        "| 2 | acceptance | not run: geometric path: the simulated sensor measures no images" in md
    )
    assert "| - |" in md and "0/0" not in md
    assert "## 2. Sensor acceptance (acceptance): not run: geometric path" in md
    h = to_json(journal)["headline"]
    assert h["passed"] == 2 and list(h["not_run"]) == ["acceptance"]
    assert h["acceptance"].startswith("not run: geometric path")
    # run again: not run earlier, not run again
    said.clear()
    assert run_sequence(ctx, Journal(tmp_path, SETUP, proc)) is None  # type: ignore[arg-type]
    assert "step 2/3 acceptance: not run earlier (geometric path" in "\n".join(said)
    assert counts_text(journal) == "2 of 3 steps passed, 1 not run (acceptance)"


def test_the_acceptance_says_it_is_adapted_how_with_a_legend_and_the_frame(
    tmp_path: Path,
) -> None:
    """The rendered acceptance widens SD's limit by the robot's share (0.015 -> 0.119 mm)
    under the title VDI/VDE 2634-2: the report says it is adapted and how, what PF, PS and SD
    are (REFERENCE.md's names) and the frame of the positions."""
    title = COMMISSIONING.titles["acceptance"]
    assert title == "Sensor acceptance (adapted from VDI/VDE 2634-2: PF, PS, SD)"
    assert "adapted from VDI/VDE 2634 Part 2" in METHOD and "robot's share" in METHOD
    assert LEGEND["PF"].startswith("probing error form")
    assert LEGEND["PS"].startswith("probing error size")
    assert LEGEND["SD"].startswith("sphere-spacing error")
    assert "in the sensor frame" in LEGEND["positions"]
    journal = Journal(tmp_path, SETUP)
    message = "PF 117.4 um ..., within 150.0 um; SD +3.4 um ..., within +-119.0 um"
    _finish(journal, "acceptance", method=METHOD, legend=dict(LEGEND), message=message)
    md = markdown(journal)
    assert "## 8. Sensor acceptance (adapted from VDI/VDE 2634-2: PF, PS, SD)" in md
    assert f"- method: {METHOD}" in md
    assert f"  - SD: {LEGEND['SD']}" in md and f"  - positions: {LEGEND['positions']}" in md
    assert f"- Sensor acceptance: passed: {message}." in md.split("| # | step |")[0]
