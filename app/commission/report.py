"""The commissioning report, `commission/commission.md` and `commission/commission.json`,
rewritten from the journal after every step: what was set up, the steps passed and those that
did not run here (counted apart, with why), the headline figures (the cell's U95 and what it
is, the limit the service holds it to, VDA 5's ratio or why none, a tolerance that may be a
half-range questioned, the workspace RMSE, the sensor acceptance), each step's checks against
their limits (with their units; shares in per cent with their counts), its figures and files,
how many times it ran and why it ran again (an earlier run interrupted or failed), and what is
left.

Figures are written whole, nested ones as sub-lists or tables; figures in millimetres (named
`..._mm`) to a tenth of a micrometre, as the checks state them. The simulated line's truth
(results named `truth` or `true_...`: what no real cell can know) is marked "simulation only".
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from app.commission.checks import MM, Check
from app.commission.journal import (
    FAILED,
    INTERRUPTED,
    NOT_RUN,
    NOT_RUN_KEY,
    STARTED,
    Journal,
    StepRecord,
)
from app.formats.files import dumps_json, write_text


def format_value(c: Check) -> str:
    """A check's value with its unit, numbers as the check says (`Check.fmt`; else to 4
    significant digits)."""
    unit = f" {c.unit}" if c.unit else ""
    if isinstance(c.value, float):
        return f"{c.value:{c.fmt or '.4g'}}{unit}"
    return f"{c.value}{unit if not isinstance(c.value, bool) else ''}"


def limit_of(c: Check) -> str:
    """A check's limit as the report writes it ("-": a figure stated, not checked)."""
    return c.limit if c.checked else "-"


def check_line(c: Check) -> str:
    """A check as the console prints it: "ok   name: value (limit)", "FAIL ...", or the
    figure alone when it is stated, not checked; a yes/no check (`holds`: its limit "yes")
    without its limit ("FAIL every sphere in the export: missing P3, P4", not "... (yes)")."""
    if not c.checked:
        return f"     {c.name}: {format_value(c)}"
    limit = "" if c.limit == "yes" else f" ({c.limit})"
    return f"{'ok  ' if c.ok else 'FAIL'} {c.name}: {format_value(c)}{limit}"


def verdict(c: Check) -> str:
    if not c.checked:
        return "-"
    return "yes" if c.ok else "**NO**"


def cell(text: str) -> str:
    """Text in a Markdown table's cell: its "|" escaped ("|PS|" is no column)."""
    return text.replace("|", "\\|")


def check_row(c: Check) -> str:
    """A check as a row of the report's checks table."""
    return f"| {cell(c.name)} | {cell(format_value(c))} | {cell(limit_of(c))} | {verdict(c)} |"


SIMULATION_ONLY = "simulation only: the simulated cell's truth, unknown on a real cell"


def simulation_only(key: str) -> bool:
    """A result that only the simulated line can give (its truth)."""
    return key == "truth" or key.startswith("true_")


def _scalar(value: Any, key: str = "") -> str:
    """A figure on one line; named `key`: millimetres (`..._mm`) to 0.1 um."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:{MM}}" if key.endswith("_mm") else f"{value:.6g}"
    if isinstance(value, list | tuple) and not value:
        return "none"
    if isinstance(value, list | tuple) and all(not isinstance(v, dict | list) for v in value):
        return ", ".join(_scalar(v, key) for v in value)
    if isinstance(value, dict | list | tuple):
        return json.dumps(value, default=str)
    return str(value)


def _is_scalar(value: Any) -> bool:
    """A number, a text, or a list of them (one line)."""
    if isinstance(value, dict):
        return False
    return not isinstance(value, list | tuple) or all(
        not isinstance(v, dict | list | tuple) for v in value
    )


def _table(rows: list[tuple[str, dict[str, Any]]], first: str) -> list[str]:
    """Rows (name, fields) as a Markdown table; `first`: the name column's heading ("" none)."""
    keys = list(dict.fromkeys(k for _, fields in rows for k in fields))
    head = ([first] if first else []) + keys
    out = ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, fields in rows:
        cells = ([name] if first else []) + [_scalar(fields.get(k), k) for k in keys]
        out.append("| " + " | ".join(map(cell, cells)) + " |")
    return [*out, ""]


def _results(results: dict[str, Any]) -> list[str]:
    """Each figure whole: a scalar or list on its line, a dict as a sub-list, a list of
    records or a dict of records as a table."""
    lines = []
    for key, value in results.items():
        label = f"{key} ({SIMULATION_ONLY})" if simulation_only(key) else key
        if _is_scalar(value):
            lines.append(f"- {label}: {_scalar(value, key)}")
        elif isinstance(value, dict) and all(_is_scalar(v) for v in value.values()):
            lines.append(f"- {label}:")
            lines += [f"  - {k}: {_scalar(v, k)}" for k, v in value.items()]
        elif isinstance(value, dict) and all(isinstance(v, dict) for v in value.values()):
            lines.append(f"- {label}:")
            lines += _table([(str(k), v) for k, v in value.items()], "name")
        elif isinstance(value, list) and all(isinstance(v, dict) for v in value):
            lines.append(f"- {label}:")
            lines += _table([("", v) for v in value], "")
        else:
            lines.append(f"- {label}: {json.dumps(value, default=str)}")
    return lines


def status_of(rec: StepRecord) -> str:
    """A step's status as the report says it (`started` found later: interrupted)."""
    return INTERRUPTED if rec.status == STARTED else rec.status


def status_text(rec: StepRecord) -> str:
    """The status with a step's reason for not running ("not run: geometric path: ...")."""
    if rec.status == NOT_RUN:
        return f"{NOT_RUN}: {rec.results.get(NOT_RUN_KEY) or 'not applicable here'}"
    return status_of(rec)


def _runs(rec: StepRecord) -> str:
    """ "Run 3 times: interrupted (started ...), failed (started ...: checks ...), then passed."."""
    if not rec.earlier:
        return ""
    parts = []
    for e in rec.earlier:
        failed = e.get("failed_checks") or []
        why = f"; failed {', '.join(failed)}" if failed else ""
        parts.append(f"{e['status']} (started {e['started_utc']}{why})")
    return f"Run {len(rec.earlier) + 1} times: {', '.join(parts)}, then {status_of(rec)}."


def _again(journal: Journal) -> str:
    """ "Run again: calibration (after 1 interrupted run), sensor (after 1 failed run)." ("":
    every step ran once)."""
    parts = []
    for name in journal.procedure.names:
        rec = journal.steps.get(name)
        if rec is None or not rec.earlier:
            continue
        counts = Counter(e["status"] for e in rec.earlier)
        runs = ", ".join(f"{n} {status} run{'s' if n > 1 else ''}" for status, n in counts.items())
        parts.append(f"{name} (after {runs})")
    return f"Run again: {', '.join(parts)}." if parts else ""


def counts_text(journal: Journal) -> str:
    """ "9 of 10 steps passed, 1 not run (acceptance)": passed and not run counted apart."""
    names = journal.procedure.names
    passed = [s for s in names if journal.passed(s)]
    not_run = [s for s in names if journal.not_run(s) is not None]
    head = f"{len(passed)} of {len(names)} steps passed"
    return head + (f", {len(not_run)} not run ({', '.join(not_run)})" if not_run else "")


def headline(journal: Journal) -> dict[str, Any]:
    """The figures a reader wants first, from the steps that give them: the steps passed and
    not run; the cell's U95 and what it is, the limit the service holds it to and its basis,
    the tolerance as read and VDA 5's ratio (or why none), a tolerance questioned as a
    possible half-range (the workspace step, app/commission/workspace.py; the limit as the
    ready step wrote it when it ran); the workspace RMSE; the sensor acceptance's outcome;
    a maintenance's workspace RMS before and after ({} of a procedure with none of them)."""
    names = journal.procedure.names
    out: dict[str, Any] = {
        "steps": len(names),
        "passed": sum(journal.passed(s) for s in names),
        "not_run": {s: why for s in names if (why := journal.not_run(s)) is not None},
    }
    ws = journal.steps.get("workspace")
    if ws is not None and ws.status != STARTED and "u95_mm" in ws.results:
        w = ws.results
        out |= {k: w[k] for k in _HEADLINE_KEYS if k in w}
        ready = journal.steps.get("ready")
        if ready is not None and "accuracy_limit_mm" in ready.results:
            out["accuracy_limit_mm"] = ready.results["accuracy_limit_mm"]  # as written
        out["workspace_rmse_mm"] = w.get("rmse_mm")
        out["workspace_rmse_95_interval_mm"] = w.get("rmse_95_interval_mm")
        out["workspace_positions"] = f"{w.get('measured')} of {w.get('positions')}"
        if "true_rmse_mm" in w:
            out["true_rmse_mm"] = w["true_rmse_mm"]
    acc = journal.steps.get("acceptance")
    if acc is not None and acc.status != STARTED:
        if acc.status == NOT_RUN:
            out["acceptance"] = f"not run: {acc.results.get(NOT_RUN_KEY)}"
        elif "message" in acc.results:
            verdict = "failed" if acc.status == FAILED else "passed"
            out["acceptance"] = f"{verdict}: {acc.results['message']}"
    return out


#: the workspace step's results the headline repeats
_HEADLINE_KEYS = (
    "u95_mm",
    "u95_what",
    "accuracy_limit_mm",
    "accuracy_limit_basis",
    "tolerance_mm",
    "tolerance",
    "vda5_ratio",
    "vda5_ratio_not_stated",
    "tolerance_question",
    "workspace_change",
    "workspace_shown_worse",
)


def headline_lines(h: dict[str, Any]) -> list[str]:
    """The headline as the report's first section (Markdown bullets; [] without figures)."""
    lines = []
    if "u95_mm" in h:
        lines.append(f"- **U95 {h['u95_mm']:{MM}} mm**: {h['u95_what']}.")
        lines.append(
            f"- **Limit the service holds it to: {h['accuracy_limit_mm']:{MM}} mm**"
            f" (`[service] accuracy_limit_mm`): {h['accuracy_limit_basis']}; a window whose U95"
            " is above it is not vouched for (its bodies suspect)."
        )
        if "vda5_ratio" in h:
            lines.append(
                f"- **VDA 5 capability 2 U95 / T: {100 * h['vda5_ratio']:.1f} %** (at most 30 %);"
                f" tolerance {h['tolerance']}."
            )
        else:
            lines.append(f"- **VDA 5 capability: not stated**: {h.get('vda5_ratio_not_stated')}.")
        if "tolerance_question" in h:
            lines.append(f"- **WARNING: {h['tolerance_question']}.**")
        lo, hi = h.get("workspace_rmse_95_interval_mm") or (None, None)
        interval = f" (95 % interval {lo:{MM}}-{hi:{MM}} mm)" if lo is not None else ""
        truth = (
            f"; the simulated cell's truth {h['true_rmse_mm']:{MM}} mm ({SIMULATION_ONLY})"
            if "true_rmse_mm" in h
            else ""
        )
        lines.append(
            f"- Workspace RMSE {h['workspace_rmse_mm']:{MM}} mm{interval} at"
            f" {h['workspace_positions']} positions{truth}."
        )
        if "workspace_change" in h:
            warn = "**WARNING: " if h.get("workspace_shown_worse") else ""
            lines.append(f"- {warn}{h['workspace_change']}{'**' if warn else ''}.")
        if h["u95_mm"] > h["accuracy_limit_mm"]:
            lines.append(
                "- **WARNING: U95 is above the limit: the service starts this cell unable to"
                " vouch for its windows (their bodies suspect) until its own measurements bring"
                " U95 under the limit.**"
            )
    if "acceptance" in h:
        lines.append(f"- Sensor acceptance: {h['acceptance']}.")
    return ["## Headline", "", *lines, ""] if lines else []


def markdown(journal: Journal) -> str:
    proc = journal.procedure
    names, titles = proc.names, proc.titles
    nxt = journal.next_step()
    setup = ", ".join(f"{k} {v}" for k, v in journal.setup.items())
    lines = [
        f"# {proc.title}",
        "",
        f"Set-up: {setup}.",
        "",
        f"**{counts_text(journal)}**" + (f"; {proc.done}." if nxt is None else f"; next: `{nxt}`."),
        "",
        *headline_lines(headline(journal)),
        *([again, ""] if (again := _again(journal)) else []),
        "| # | step | status | checks passed | seconds | runs |",
        "|---|------|--------|---------------|---------|------|",
    ]
    for i, name in enumerate(names, start=1):
        rec = journal.steps.get(name)
        if rec is None:
            lines.append(f"| {i} | {name} | not run yet | | | |")
            continue
        checked = [c for c in rec.checks if c.checked]
        ok = sum(c.ok for c in checked)
        counted = "-" if rec.status == NOT_RUN else f"{ok}/{len(checked)}"
        lines.append(
            f"| {i} | {name} | {cell(status_text(rec))} | {counted} | {rec.seconds:.1f} |"
            f" {len(rec.earlier) + 1} |"
        )
    for i, name in enumerate(names, start=1):
        rec = journal.steps.get(name)
        if rec is None:
            continue
        lines += ["", f"## {i}. {titles[name]} ({name}): {status_text(rec)}", ""]
        if rec.status == STARTED:
            lines.append(f"Started {rec.started_utc}; interrupted (no outcome): it runs again.")
        elif rec.status == NOT_RUN:
            lines.append(f"Started {rec.started_utc}, {rec.seconds:.1f} s; nothing checked.")
        else:
            lines.append(f"Started {rec.started_utc}, {rec.seconds:.1f} s.")
        if rec.earlier:
            lines.append(_runs(rec))
        if rec.checks:
            lines += ["", "| check | value | limit | ok |", "|---|---|---|---|"]
            lines += [check_row(c) for c in rec.checks]
        results = {k: v for k, v in rec.results.items() if k != NOT_RUN_KEY}
        if results:
            lines += ["", *_results(results)]
        if rec.files:
            lines += ["", "Files: " + ", ".join(f"`{f}`" for f in rec.files)]
    return "\n".join(lines) + "\n"


def to_json(journal: Journal) -> dict[str, Any]:
    names = journal.procedure.names
    return {
        "setup": journal.setup,
        "complete": journal.next_step() is None,
        "next_step": journal.next_step(),
        "headline": headline(journal),
        "steps": [journal.steps[s].to_json() for s in names if s in journal.steps],
    }


def write_report(journal: Journal) -> tuple[Path, Path]:
    proc = journal.procedure
    md, js = journal.folder / proc.report_md, journal.folder / proc.report_json
    write_text(md, markdown(journal))
    write_text(js, dumps_json(to_json(journal), indent=2) + "\n")
    return md, js
