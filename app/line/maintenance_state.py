"""A cell in maintenance as the world sees it (issue 41): the status reply's `maintenance`, and
the same from the files when no service runs (`rvis status`), its words for `rvis status` and
the TUI, and the Machinery operation mode OPC UA publishes from it. Light: no numerics (the
light commands import it: tests/app/test_light_commands.py).

Three facts, each from its own home:

- `needed`: the `maintenance` alarm in force (a FAULT code, app.line.states; raised by the
  service for a change beyond a knock, app.line.beyond_knock), what its text says moved and
  the procedures it names (the `rvis maintain ...` or `rvis commission ...` commands its text
  quotes in backticks);
- `running`: a maintenance record still `running` (app.line.store, table `maintenance`: the
  procedure in progress, or stopped half-way), with how far its journal got (the procedure's
  folder's journal.json and report, app/commission/journal.py's format: the steps passed, the
  next step to run);
- `last_done`: the last record `done` (the cell handed back), with its versions before and
  after.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from app.line.statedir import JOURNAL_NAME, MAINTENANCE_REPORT_JSON
from app.line.states import AlarmCode, alarm_detail, utc_text

#: the maintenance records a status reply carries (the newest ones)
RECORDS_IN_STATUS = 5

#: the commands a `maintenance` alarm's text names, in backticks
_COMMAND = re.compile(r"`(rvis (?:maintain|commission)\b[^`]*)`")

#: OPC 40001-1's MachineryOperationMode (MachineryOperationModeStateMachineType's states)
MODE_NONE, MODE_MAINTENANCE, MODE_PROCESSING = "None", "Maintenance", "Processing"


def need_of(alarm: Mapping[str, Any]) -> dict[str, Any]:
    """The `maintenance` alarm as a need: its id, state, when raised, what moved and the
    procedures that fit, from the fields stored beside its text (app.line.beyond_knock.
    MaintenanceNeed: `detail`, with the group named and the change at the spheres); an alarm
    from before them (a database of an older rvis): its text's `likely ...` clause, else its
    first, and the commands it quotes."""
    text = str(alarm.get("message") or alarm.get("text") or "")
    detail = alarm_detail(alarm)
    if detail is not None and "what" in detail:
        fields = {
            "what": str(detail["what"]),
            "procedures": [str(p) for p in detail.get("procedures") or ()],
            "group": detail.get("group") or None,
            "moved_mm": detail.get("moved_mm"),
        }
    else:
        clauses = [c.strip() for c in text.split("; ")]
        likely = [c for c in clauses if c.startswith("likely ")]
        fields = {
            "what": likely[0] if likely else clauses[0],
            "procedures": _COMMAND.findall(text),
            "group": None,
            "moved_mm": None,
        }
    t = alarm.get("t_raised")
    return {
        "alarm_id": alarm.get("id"),
        "state": alarm.get("state"),
        "raised_utc": alarm.get("raised_utc") or (None if t is None else utc_text(float(t))),
        **fields,
        "text": text,
    }


#: a journal's statuses of a step done: passed, or found not to run on this path (the
#: acceptance on the geometric path; app/commission/journal.py)
_DONE = ("passed", "not run")


def progress_of(folder: Path) -> dict[str, Any]:
    """How far a procedure's journal got: the steps passed (names, in order), those that could
    not run on this path (`not_run`), the step to run next and its status in the journal
    (`started`: running now or interrupted; `failed`; None: not run yet). The next step is the
    first one journalled and not done, else the report's `next_step` (the journal lists only
    the steps run so far)."""
    journal = _read(folder / JOURNAL_NAME)
    steps = [s for s in journal.get("steps") or () if isinstance(s, dict)]
    passed = [str(s.get("name")) for s in steps if s.get("status") == "passed"]
    not_run = [str(s.get("name")) for s in steps if s.get("status") == "not run"]
    current = next((s for s in steps if s.get("status") not in _DONE), None)
    if current is not None:
        nxt, status = current.get("name"), current.get("status")
    else:
        nxt, status = _read(folder / MAINTENANCE_REPORT_JSON).get("next_step"), None
    out = {"steps_passed": len(passed), "passed": passed, "next_step": nxt, "next_status": status}
    return out | ({"not_run": not_run} if not_run else {})


def _read(path: Path) -> dict[str, Any]:
    """A JSON document, or {} when it is absent or unreadable (being replaced)."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def record_json(row: Mapping[str, Any], root: Path | None = None) -> dict[str, Any]:
    """A maintenance record as the status reply carries it; a running one with its journal's
    progress when the state directory `root` is given."""
    t_end = row.get("t_end")
    out = {
        "id": row.get("id"),
        "event": row.get("event"),
        "axis": row.get("axis"),
        "who": row.get("who"),
        "folder": row.get("folder"),
        "status": row.get("status"),
        "start_utc": utc_text(float(row["t_start"])),
        "end_utc": None if t_end is None else utc_text(float(t_end)),
        "version_before": row.get("version_before"),
        "version_after": row.get("version_after"),
        "before": row.get("before") or {},
        "after": row.get("after") or {},
    }
    if row.get("status") == "running" and root is not None and row.get("folder"):
        out["progress"] = progress_of(Path(root) / str(row["folder"]))
    return out


def maintenance_json(
    alarms: Sequence[Mapping[str, Any]], records: Sequence[Mapping[str, Any]], root: Path | None
) -> dict[str, Any]:
    """The status reply's `maintenance`: `needed` (the `maintenance` alarm in force, else
    None), `running` (the newest record still running and not superseded by a later one
    done, with its progress), `last_done` (the newest record done) and `records` (the last
    RECORDS_IN_STATUS, oldest first). `records`: in time order (Store.maintenance)."""
    active = [a for a in alarms if a.get("code") == AlarmCode.MAINTENANCE]
    done = [r for r in records if r.get("status") == "done"]
    # a record left running before a later one handed the cell back (begun again with
    # `--restart`) is superseded: the cell is not in maintenance for it
    after = done[-1]["id"] if done else -1
    running = [r for r in records if r.get("status") == "running" and r["id"] > after]
    return {
        "needed": need_of(active[-1]) if active else None,
        "running": record_json(running[-1], root) if running else None,
        "last_done": record_json(done[-1]) if done else None,
        "records": [record_json(r) for r in records[-RECORDS_IN_STATUS:]],
    }


def operation_mode(status: Mapping[str, Any]) -> str:
    """OPC 40001-1's MachineryOperationMode of a status reply (what the cell is set up for;
    MachineryItemState says what it does): Maintenance while the `maintenance` alarm is in
    force, or while a procedure is recorded running and the service does not measure (paused,
    in another fault, starting or stopped); Processing while the service waits for or measures
    in a window (an engineer reset the cell without finishing the procedure), is paused or in
    another fault; None while it starts or stops."""
    m = status.get("maintenance") or {}
    state = status.get("state")
    if m.get("needed") or (m.get("running") and state not in ("idle", "measuring")):
        return MODE_MAINTENANCE
    if state in ("idle", "measuring", "paused", "fault"):
        return MODE_PROCESSING
    return MODE_NONE


def record_event(r: Mapping[str, Any]) -> str:
    """`axis (axis 3)`, `sensor`."""
    axis = r.get("axis")
    return f"{r.get('event')}" + (f" (axis {axis})" if axis is not None else "")


def procedures_text(need: Mapping[str, Any]) -> str:
    """`run `rvis maintain axis 3`` (or several, "or")."""
    procs = need.get("procedures") or []
    return "run " + " or ".join(f"`{p}`" for p in procs) if procs else "see the alarm"


def needed_text(need: Mapping[str, Any]) -> str:
    """`<what moved>; run `rvis maintain ...``."""
    return f"{need.get('what')}; {procedures_text(need)}"


def progress_text(progress: Mapping[str, Any] | None) -> str:
    """`2 steps passed, next: zero (started)`."""
    if not progress:
        return "its journal unknown"
    k, nxt = progress.get("steps_passed", 0), progress.get("next_step")
    head = f"{k} step{'' if k == 1 else 's'} passed"
    if progress.get("not_run"):
        head += f", {len(progress['not_run'])} not run ({', '.join(progress['not_run'])})"
    if nxt is None:
        return f"{head}, none run yet" if not k else f"{head}, every step passed"
    status = progress.get("next_status")
    return f"{head}, next: {nxt}" + (f" ({status})" if status else "")


def running_text(r: Mapping[str, Any]) -> str:
    """`axis (axis 3) since <utc>, by <who>, 2 steps passed, next: zero, folder
    maintenance/0001-axis3`."""
    return (
        f"{record_event(r)} since {r.get('start_utc')}, by {r.get('who')},"
        f" {progress_text(r.get('progress'))}, folder {r.get('folder')}"
    )


def done_text(r: Mapping[str, Any]) -> str:
    """`axis (axis 3) done <utc>, by <who>, version 1 -> 2 (workspace validation RMS 0.060
    -> 0.079 mm, worse by 0.019 mm, +32 %)`: the change said, not left to the reader."""

    def rms(doc: Any) -> float | None:
        value = (doc or {}).get("validation_rmse_mm")
        return float(value) if isinstance(value, int | float) else None

    before, after = rms(r.get("before")), rms(r.get("after"))
    figures = " -> ".join("-" if v is None else f"{v:.3f}" for v in (before, after))
    return (
        f"{record_event(r)} done {r.get('end_utc')}, by {r.get('who')},"
        f" version {r.get('version_before') or '-'} -> {r.get('version_after') or '-'}"
        f" (workspace validation RMS {figures} mm{change_words(before, after)})"
    )


def change_words(before: float | None, after: float | None) -> str:
    """ ", worse by 0.019 mm, +32 %" / ", better by ..." / ", unchanged" ("" without both)."""
    if before is None or after is None:
        return ""
    delta = after - before
    if round(abs(delta), 3) == 0:
        return ", unchanged"
    way = "worse" if delta > 0 else "better"
    share = f", {100 * delta / before:+.0f} %" if before > 0 else ""
    return f", {way} by {abs(delta):.3f} mm{share}"


def maintenance_lines(m: Mapping[str, Any] | None) -> list[str]:
    """The maintenance's lines of `rvis status` (none when there is nothing to say)."""
    if not m:
        return []
    out = []
    if m.get("needed"):
        out.append(f"maintenance needed  {needed_text(m['needed'])}")
    if m.get("running"):
        out.append(f"in maintenance      {running_text(m['running'])}")
    if m.get("last_done"):
        out.append(f"last maintenance    {done_text(m['last_done'])}")
    return out
