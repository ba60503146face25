"""The commissioning's journal, `STATE_DIR/commission/journal.json`: how it was started (the
set-up: cell file, simulated or not, seed) and every step run so far with its checks, results
and files, replaced atomically after each step. A step counts as done once it passed, or once it
found it cannot run on this path (`not run`, with its reason: never counted as passed); a failed
or interrupted step runs again next time.

A step is journalled as `started` before it runs: found so at the next run, it was interrupted
(the process was killed, the machine went down). Each record keeps its step's earlier runs
(`earlier`: when each started, and whether it was interrupted or failed, with the checks that
failed), so the report can say that a step ran more than once and why."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.commission.checks import Check
from app.commission.table import COMMISSIONING, Procedure
from app.errors import InputError
from app.formats.files import read_json, write_json
from app.line.statedir import JOURNAL_NAME

PASSED, FAILED, STARTED = "passed", "failed", "started"
INTERRUPTED = "interrupted"  # an earlier run found `started`
#: a step that cannot run on this path (StepResult.not_run, its reason in the results under
#: NOT_RUN_KEY): done, so the procedure goes on, but counted and reported apart from passed
NOT_RUN = "not run"
NOT_RUN_KEY = "not_run"


@dataclass(frozen=True)
class StepRecord:
    name: str
    status: str
    started_utc: str
    seconds: float
    checks: tuple[Check, ...]
    results: dict[str, Any]
    files: tuple[str, ...]
    earlier: tuple[dict[str, Any], ...] = ()  # the step's earlier runs, oldest first

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> StepRecord:
        checks = tuple(Check(**c) for c in doc["checks"])
        earlier = tuple(dict(e) for e in doc.get("earlier", ()))
        return cls(**{**doc, "checks": checks, "files": tuple(doc["files"]), "earlier": earlier})

    def as_earlier(self) -> dict[str, Any]:
        """This run as an earlier one: when it started, how it ended, the checks it failed."""
        status = INTERRUPTED if self.status == STARTED else self.status
        failed = [c.name for c in self.checks if not c.ok]
        return {"started_utc": self.started_utc, "status": status, "failed_checks": failed}


class Journal:
    """`Journal(folder, setup)`: the journal of the commissioning (or another `procedure`) in
    `folder`, created or continued; a journal started with another set-up is refused
    (InputError: `--restart`)."""

    def __init__(
        self, folder: Path, setup: dict[str, Any], procedure: Procedure = COMMISSIONING
    ) -> None:
        self.folder, self.setup, self.procedure = folder, setup, procedure
        fmt = procedure.journal_format
        self.path = folder / JOURNAL_NAME
        self.steps: dict[str, StepRecord] = {}
        self._before: dict[str, StepRecord | None] = {}  # the records of the steps running
        if self.path.exists():
            doc = read_json(self.path)
            if doc.get("format") != fmt:
                raise InputError(f"not an {fmt} journal", file=self.path, field="format")
            if doc.get("setup") != setup:
                raise InputError(
                    f"this commissioning was started with {doc.get('setup')}, not {setup}: run "
                    "it the same way, or with --restart to begin again",
                    file=self.path,
                )
            try:
                self.steps = {d["name"]: StepRecord.from_json(d) for d in doc["steps"]}
            except (KeyError, TypeError) as exc:
                raise InputError(f"malformed step ({exc})", file=self.path) from None

    def passed(self, name: str) -> bool:
        record = self.steps.get(name)
        return record is not None and record.status == PASSED

    def not_run(self, name: str) -> str | None:
        """Why step `name` did not run (None: it ran, or has not been reached)."""
        record = self.steps.get(name)
        if record is None or record.status != NOT_RUN:
            return None
        return str(record.results.get(NOT_RUN_KEY) or "not applicable here")

    def done(self, name: str) -> bool:
        """Passed, or found not to run on this path: the procedure goes on past it."""
        return self.passed(name) or self.not_run(name) is not None

    def next_step(self) -> str | None:
        """The first step not done yet (None: every step passed or could not run here)."""
        return next((s for s in self.procedure.names if not self.done(s)), None)

    def start(self, name: str, started_utc: str) -> None:
        """Journal that step `name` starts now (its earlier runs kept)."""
        prev = self.steps.get(name)
        self._before[name] = prev
        earlier = () if prev is None else (*prev.earlier, prev.as_earlier())
        self.record(StepRecord(name, STARTED, started_utc, 0.0, (), {}, (), earlier))

    def finish(self, record: StepRecord) -> None:
        """The step's outcome, with the earlier runs `start` journalled."""
        started = self.steps.get(record.name)
        earlier = started.earlier if started is not None else ()
        self._before.pop(record.name, None)
        self.record(dataclasses.replace(record, earlier=earlier))

    def abandon(self, name: str) -> None:
        """The engineer stopped the step: the journal as it was before it started."""
        prev = self._before.pop(name, None)
        if prev is None:
            self.steps.pop(name, None)
            self._write()
        else:
            self.record(prev)

    def record(self, record: StepRecord) -> None:
        self.steps[record.name] = record
        self._write()

    def _write(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        ordered = [self.steps[s].to_json() for s in self.procedure.names if s in self.steps]
        fmt = self.procedure.journal_format
        write_json(self.path, {"format": fmt, "setup": self.setup, "steps": ordered})
