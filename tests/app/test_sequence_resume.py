"""A journal resumed with a step it has no record of before steps it passed (a commissioning
started by an older rvis, whose procedure had no pre-calibration: the plan passed then was made
on the nominal parameters): the new step runs, and every step after it runs again on what it
gives, instead of keeping results made without it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from app.commission.checks import StepResult, holds
from app.commission.journal import PASSED, Journal
from app.commission.sequence import run_sequence
from app.commission.table import CommissionStep, Procedure

SETUP = {"cell": "cell.toml", "sim": True}


def _procedure(ran: list[str], names: tuple[str, ...]) -> Procedure:
    def step(name: str) -> CommissionStep:
        def run(ctx: object) -> StepResult:
            ran.append(name)
            return StepResult([holds("ok", True)])

        return CommissionStep(name, name.title(), run)

    return Procedure(
        tuple(step(n) for n in names), "Report", "r.md", "r.json", "done", "rvis-test/1"
    )


def test_a_step_new_to_the_journal_runs_and_the_steps_after_it_run_again(tmp_path: Path) -> None:
    said: list[str] = []
    ctx = SimpleNamespace(say=said.append, ask=lambda question: None, truth=None, robot_s=0.0)
    ran: list[str] = []
    # the older procedure: devices, plan, calibration, all passed
    old = _procedure(ran, ("devices", "plan", "calibration"))
    assert run_sequence(ctx, Journal(tmp_path, SETUP, old)) is None  # type: ignore[arg-type]
    assert ran == ["devices", "plan", "calibration"]
    # resumed by a procedure with a step before the plan: it runs, then the plan and the
    # calibration again; the devices' step before it stays passed
    ran.clear()
    said.clear()
    new = _procedure(ran, ("devices", "precalibration", "plan", "calibration"))
    journal = Journal(tmp_path, SETUP, new)
    assert run_sequence(ctx, journal) is None  # type: ignore[arg-type]
    assert ran == ["precalibration", "plan", "calibration"]
    text = "\n".join(said)
    assert "step 1/4 devices: passed earlier" in text
    assert "step 3/4 plan: done earlier, runs again after step precalibration" in text
    assert all(journal.steps[n].status == PASSED for n in new.names)
    assert [e["status"] for e in journal.steps["plan"].earlier] == [PASSED]
    # all passed now: a third run runs nothing
    ran.clear()
    assert run_sequence(ctx, Journal(tmp_path, SETUP, new)) is None  # type: ignore[arg-type]
    assert ran == []
