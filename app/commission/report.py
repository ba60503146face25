"""The commissioning report, `commission/commission.md` and `commission/commission.json`,
rewritten from the journal after every step: what was set up, each step's checks against their
limits, its figures and files, and what is left."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from app.commission.journal import STEPS, Check, Journal
from app.formats.files import dumps_json, write_text

TITLES = {
    "devices": "Devices answer",
    "stripe": "Laser stripe seen by the camera",
    "sensor": "Sensor calibration",
    "spheres": "Sphere positions from the tracker",
    "plan": "Measurement plan",
    "calibration": "First calibration",
    "acceptance": "Sensor acceptance (VDI/VDE 2634-2: PF, PS, SD)",
    "validation": "Quick check: the calibration spheres from new views",
    "workspace": "Validation at workspace positions against the tracker (the paper's)",
    "ready": "State directory ready for `rvis run`",
}


def format_value(c: Check) -> str:
    """A check's value with its unit, numbers to 4 significant digits."""
    if isinstance(c.value, float):
        return f"{c.value:.4g}{' ' + c.unit if c.unit else ''}"
    return f"{c.value}{' ' + c.unit if c.unit and not isinstance(c.value, bool) else ''}"


def _results(results: dict[str, Any]) -> list[str]:
    lines = []
    for key, value in results.items():
        if isinstance(value, float):
            text = f"{value:.6g}"
        elif isinstance(value, str):
            text = value
        else:
            text = json.dumps(value, default=str)
            text = text if len(text) <= 400 else text[:400] + " ..."
        lines.append(f"- {key}: {text}")
    return lines


def markdown(journal: Journal) -> str:
    done = [s for s in STEPS if journal.passed(s)]
    nxt = journal.next_step()
    setup = ", ".join(f"{k} {v}" for k, v in journal.setup.items())
    lines = [
        "# Commissioning report",
        "",
        f"Set-up: {setup}.",
        "",
        f"**{len(done)} of {len(STEPS)} steps passed**"
        + ("; the cell is ready for `rvis run`." if nxt is None else f"; next: `{nxt}`."),
        "",
        "| # | step | status | checks passed | seconds |",
        "|---|------|--------|---------------|---------|",
    ]
    for i, name in enumerate(STEPS, start=1):
        rec = journal.steps.get(name)
        if rec is None:
            lines.append(f"| {i} | {name} | not run | | |")
            continue
        ok = sum(c.ok for c in rec.checks)
        lines.append(
            f"| {i} | {name} | {rec.status} | {ok}/{len(rec.checks)} | {rec.seconds:.1f} |"
        )
    for i, name in enumerate(STEPS, start=1):
        rec = journal.steps.get(name)
        if rec is None:
            continue
        lines += ["", f"## {i}. {TITLES[name]} ({name}): {rec.status}", ""]
        lines.append(f"Started {rec.started_utc}, {rec.seconds:.1f} s.")
        lines += ["", "| check | value | limit | ok |", "|---|---|---|---|"]
        lines += [
            f"| {c.name} | {format_value(c)} | {c.limit} | {'yes' if c.ok else '**NO**'} |"
            for c in rec.checks
        ]
        if rec.results:
            lines += ["", *_results(rec.results)]
        if rec.files:
            lines += ["", "Files: " + ", ".join(f"`{f}`" for f in rec.files)]
    return "\n".join(lines) + "\n"


def to_json(journal: Journal) -> dict[str, Any]:
    return {
        "setup": journal.setup,
        "complete": journal.next_step() is None,
        "next_step": journal.next_step(),
        "steps": [journal.steps[s].to_json() for s in STEPS if s in journal.steps],
    }


def write_report(journal: Journal) -> tuple[Path, Path]:
    md, js = journal.folder / "commission.md", journal.folder / "commission.json"
    write_text(md, markdown(journal))
    write_text(js, dumps_json(to_json(journal), indent=2) + "\n")
    return md, js
