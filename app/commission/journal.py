"""The commissioning's journal, `STATE_DIR/commission/journal.json`: how it was started (the
set-up: cell file, simulated or not, seed) and every step run so far with its checks, results
and files, replaced atomically after each step. A step counts as done once it passed; a failed
or interrupted step runs again next time."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.errors import InputError
from app.formats.files import read_json, write_json

FORMAT = "rvis-commission/1"
STEPS = (
    "devices",
    "stripe",
    "sensor",
    "spheres",
    "plan",
    "calibration",
    "acceptance",
    "validation",
    "workspace",
    "ready",
)
PASSED, FAILED = "passed", "failed"


@dataclass(frozen=True)
class Check:
    """One checked figure: its value, the limit it is held to (as text: "<= 0.1") and whether
    it passed; `unit` for the report."""

    name: str
    value: float | int | str | bool
    limit: str
    ok: bool
    unit: str = ""


def at_most(name: str, value: float, limit: float, unit: str = "") -> Check:
    return Check(name, float(value), f"<= {limit:g}", bool(value <= limit), unit)


def at_least(name: str, value: float, limit: float, unit: str = "") -> Check:
    return Check(name, float(value), f">= {limit:g}", bool(value >= limit), unit)


def holds(name: str, ok: bool, detail: str = "") -> Check:
    return Check(name, detail or ("yes" if ok else "no"), "yes", bool(ok))


@dataclass
class StepResult:
    """What a step returns: its checks, the figures the report shows, the files it wrote
    (relative to the commission folder)."""

    checks: list[Check] = field(default_factory=list)
    results: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.ok for c in self.checks)


@dataclass(frozen=True)
class StepRecord:
    name: str
    status: str
    started_utc: str
    seconds: float
    checks: tuple[Check, ...]
    results: dict[str, Any]
    files: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> StepRecord:
        checks = tuple(Check(**c) for c in doc["checks"])
        return cls(**{**doc, "checks": checks, "files": tuple(doc["files"])})


class Journal:
    """`Journal(folder, setup)`: the journal of the commissioning in `folder`, created or
    continued; a journal started with another set-up is refused (InputError: `--restart`)."""

    def __init__(self, folder: Path, setup: dict[str, Any]) -> None:
        self.folder, self.setup = folder, setup
        self.path = folder / "journal.json"
        self.steps: dict[str, StepRecord] = {}
        if self.path.exists():
            doc = read_json(self.path)
            if doc.get("format") != FORMAT:
                raise InputError(f"not an {FORMAT} journal", file=self.path, field="format")
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

    def next_step(self) -> str | None:
        """The first step not passed yet (None: all passed)."""
        return next((s for s in STEPS if not self.passed(s)), None)

    def record(self, record: StepRecord) -> None:
        self.steps[record.name] = record
        self.folder.mkdir(parents=True, exist_ok=True)
        ordered = [self.steps[s].to_json() for s in STEPS if s in self.steps]
        write_json(self.path, {"format": FORMAT, "setup": self.setup, "steps": ordered})
