"""The commissioning sequence: each step not passed yet, in order, confirmed by the engineer,
checked, journalled and reported before the next may start (app/commission/__init__.py)."""

from __future__ import annotations

import time
from datetime import UTC, datetime

from app.commission.checks import StepResult, holds
from app.commission.context import Context, Declined
from app.commission.journal import (
    FAILED,
    NOT_RUN,
    NOT_RUN_KEY,
    PASSED,
    Journal,
    StepRecord,
)
from app.commission.report import check_line, write_report
from drivers.errors import DeviceError


def run_sequence(ctx: Context, journal: Journal) -> str | None:
    """Run the steps from the first one not passed; the name of the step that failed its
    checks (None: every step passed). A step done earlier after one that runs now runs again
    (a journal begun by an older rvis whose procedure lacked a step: what came after it was
    made without it). Context.Declined propagates (nothing recorded for the step the engineer
    stopped)."""
    steps = journal.procedure.steps
    n = len(steps)
    ran: str | None = None  # the first step run now: the steps after it run again
    for i, step in enumerate(steps, start=1):
        name = step.name
        if ran is not None and journal.done(name):
            # done earlier on what the step before it had given then (a journal of an older
            # rvis, with a step that was not in its procedure): its inputs may have changed
            ctx.say(f"step {i}/{n} {name}: done earlier, runs again after step {ran}")
        elif journal.passed(name):
            ctx.say(f"step {i}/{n} {name}: passed earlier")
            continue
        elif (why := journal.not_run(name)) is not None:
            ctx.say(f"step {i}/{n} {name}: not run earlier ({why})")
            continue
        ran = ran or name
        ctx.ask(f"step {i}/{n} {name}: {step.title}: start?")
        ctx.say(f"step {i}/{n} {name}: {step.title} ...")
        started = datetime.now(UTC).isoformat(timespec="seconds")
        journal.start(name, started)  # found so at the next run: this run was interrupted
        if ctx.truth is not None:  # the simulated line: its camera's noise draw (app/sim)
            failed = sum(e["status"] == FAILED for e in journal.steps[name].earlier)
            ctx.truth.step_started(name, failed)
        t0, robot0 = time.monotonic(), ctx.robot_s
        try:
            result = step.run(ctx)
        except DeviceError as exc:  # a device failed mid-step: recorded, the step runs again
            result = StepResult(checks=[holds("devices", False, f"{type(exc).__name__}: {exc}")])
        except Declined:  # the engineer stopped it: as if it had not started
            journal.abandon(name)
            raise
        seconds = time.monotonic() - t0
        if ctx.robot_s > robot0:  # the robot's time in the step (its motions and sweeps)
            result.results["robot_s"] = round(ctx.robot_s - robot0, 3)
        status = PASSED if result.passed else FAILED
        if result.not_run and result.passed:  # it could not run here: said so, not "passed"
            status = NOT_RUN
            result.results[NOT_RUN_KEY] = result.not_run
        record = StepRecord(
            name,
            status,
            started,
            round(seconds, 3),
            tuple(result.checks),
            result.results,
            tuple(result.files),
        )
        journal.finish(record)
        write_report(journal)
        for c in result.checks:
            ctx.say(f"    {check_line(c)}")
        why = f": {result.not_run}" if status == NOT_RUN else ""
        ctx.say(f"step {i}/{n} {name}: {status}{why} in {seconds:.1f} s")
        if status == FAILED:
            return name
    return None
