"""Rollbacks that hold (issue 39 item 5): a rollback to the version in force is refused with
the reason and adds no history row; a rollback in auto mode holds automatic applies (a
calibration that passes its gates waits as in approve mode) until an engineer approves one or
resumes, across a restart, and the reply and the status say so. An operator's resume only
resumes measuring. The commands run as the service loop runs them (`run_commands`), here in
the test's thread on a service that is not started: no window, no wait."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from app.commands.status import status_lines
from app.config.line import RecalibSettings
from app.formats.params import plain_document
from app.line.params_store import ParamsStore
from app.line.recalib import RecalOutcome
from app.line.roles import Roles
from app.line.states import HOLD_LIFT
from tests.line.helpers import Line, make_line

ROLES = Roles("rvis-engineers", engineers_gid=4242, service_uid=998)
OPERATOR: dict[str, Any] = {"uid": 12345, "groups": (100,)}
ENGINEER: dict[str, Any] = {"uid": 12346, "groups": (100, 4242)}


def two_versions(tmp_path: Path, lines: list[Line], **kw: Any) -> Line:
    """A service (not started) with versions 1 and 2 in its history, 2 in force."""
    first = make_line(tmp_path, **kw)
    first.close()
    doc = plain_document(first.model, first.model.nominal_x() + 1e-4, "candidate")
    assert ParamsStore(tmp_path).apply(doc) == 2
    ln = make_line(tmp_path, **kw)
    lines.append(ln)
    ln.service.roles = ROLES
    assert ln.service.version == 2
    return ln


def command(
    ln: Line,
    cmd: str,
    args: dict[str, Any] | None = None,
    *,
    uid: int | None = None,
    groups: tuple[int, ...] | None = None,
) -> dict[str, Any]:
    """One command as the socket passes it, executed as the service loop does."""
    future = ln.service.request(cmd, args, uid, groups)
    ln.service.operator.run_commands()
    reply: dict[str, Any] = future.result(0)
    return reply


def candidate(ln: Line) -> None:
    """A calibration that passes its gates arrives (as from the identification's worker)."""
    x = ln.model.nominal_x() + 2e-4
    doc = plain_document(ln.model, x, "candidate")
    ln.service.recal_done(RecalOutcome(True, (), x, doc, 0.01, 0.01, 0.02, 24, 1, 24))


def test_a_rollback_to_the_version_in_force_is_refused_with_the_reason(
    tmp_path: Path, lines: list[Line]
) -> None:
    ln = two_versions(tmp_path, lines)
    applied = len(ln.service.store.applied())
    reply = command(ln, "rollback", {"version": 2}, **ENGINEER)
    assert reply == {
        "ok": False,
        "error": "parameters version 2 is in force already: nothing to roll back",
    }
    assert len(ln.service.store.applied()) == applied and ln.service.decision.auto_hold is None
    assert command(ln, "rollback", {"version": 1}, **ENGINEER)["ok"]
    assert not command(ln, "rollback", {"version": 1}, **ENGINEER)["ok"]
    assert [a["version"] for a in ln.service.store.applied()][applied:] == [1]
    audit = [(a["cmd"], a["ok"]) for a in ln.service.store.actions()]
    assert audit == [("rollback", False), ("rollback", True), ("rollback", False)]


def test_a_rollback_in_auto_mode_holds_until_an_engineer_resumes(
    tmp_path: Path, lines: list[Line]
) -> None:
    ln = two_versions(tmp_path, lines)
    reply = command(ln, "rollback", {"version": 1}, **ENGINEER)
    assert reply["ok"] and reply["held"] and ln.service.version == 1
    assert reply["message"] == f"parameters version 1 in force; {HOLD_LIFT}"
    status = ln.service.status()
    assert status["auto_hold"]["version"] == 1 and status["auto_hold"]["uid"] == ENGINEER["uid"]
    assert any(
        line.startswith("applies             auto, HELD since") for line in status_lines(status)
    )

    ln.close()  # the hold is decision state: a restart keeps it
    ln = make_line(tmp_path)
    lines.append(ln)
    ln.service.roles = ROLES
    assert ln.service.decision.auto_hold is not None and ln.service.version == 1
    candidate(ln)
    cal = ln.service.decision.pending_calibration
    assert cal is not None and ln.service.version == 1  # waits, as in approve mode

    resumed = command(ln, "resume", **OPERATOR)
    assert resumed["ok"] and resumed["held"]
    assert resumed["message"] == f"resumed; {HOLD_LIFT} (uid 12345 is an operator)"
    resumed = command(ln, "resume", **ENGINEER)
    assert resumed["held"] and f"approve or reject calibration {cal}" in resumed["message"]
    assert command(ln, "reject", **ENGINEER)["ok"] and ln.service.decision.auto_hold is not None
    resumed = command(ln, "resume", **ENGINEER)
    assert not resumed["held"] and ln.service.decision.auto_hold is None
    assert "automatic applies go on" in resumed["message"]
    assert "HELD" not in "\n".join(status_lines(ln.service.status()))
    candidate(ln)
    assert ln.service.version == 3 and ln.service.decision.pending_calibration is None


def test_an_engineer_s_approve_lifts_the_hold(tmp_path: Path, lines: list[Line]) -> None:
    ln = two_versions(tmp_path, lines)
    assert command(ln, "rollback", {"version": 1}, **ENGINEER)["held"]
    candidate(ln)
    assert command(ln, "approve", **OPERATOR)["role"] == "engineer"  # the table's refusal
    reply = command(ln, "approve", **ENGINEER)
    assert (
        reply["ok"] and reply["version"] == 3 and "hold of the rollback lifted" in reply["message"]
    )
    assert ln.service.decision.auto_hold is None
    candidate(ln)
    assert ln.service.version == 4  # automatic again


def test_a_rollback_in_approve_mode_changes_nothing_else(tmp_path: Path, lines: list[Line]) -> None:
    ln = two_versions(tmp_path, lines, recalib=RecalibSettings(mode="approve", estimator="batch"))
    reply = command(ln, "rollback", {"version": 1}, **ENGINEER)
    assert reply == {
        "ok": True,
        "message": "parameters version 1 in force",
        "version": 1,
        "held": False,
    }
    assert ln.service.status()["auto_hold"] is None


def test_approve_or_reject_with_nothing_pending_says_so(tmp_path: Path, lines: list[Line]) -> None:
    """Issue 40's words: `ctl approve` with nothing pending said "calibration None"."""
    ln = two_versions(tmp_path, lines, recalib=RecalibSettings(mode="approve", estimator="batch"))
    for cmd in ("approve", "reject"):
        reply = command(ln, cmd, **ENGINEER)
        assert not reply["ok"], reply
        assert "no calibration is pending" in str(reply) and "None" not in str(reply)
    candidate(ln)
    pending = ln.service.decision.pending_calibration
    assert pending is not None
    reply = command(ln, "reject", {"calibration": pending + 5}, **ENGINEER)
    assert not reply["ok"] and f"calibration {pending} is" in str(reply)
