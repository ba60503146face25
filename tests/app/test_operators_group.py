"""A state directory commissioned before `[service] operators_group` was set (issue 39 item
4): `rvis state check` names what does not follow the group, with the one line that fixes it,
and the service gives it the group and modes at start (app.line.statedir.follow_group), the
OPC UA key kept 0600. The group is one of this process's own (as root: any other group), so
the tests run as root or not; the one that reads as an operator (another uid in the group)
needs root."""

from __future__ import annotations

import grp
import json
import os
import shutil
import sqlite3
import stat
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.commands.state_check import check
from app.line.launch import hold_state
from app.line.statedir import StateDir, group_fix_command, group_strays, prepare
from app.tui.history import HistoryReader
from tests.app.test_state_backup import commissioned  # noqa: F401  (a fixture)
from tests.peers import as_user

OPERATOR_UID = 54323  # no passwd entry needed


def target_group() -> tuple[str, int]:
    """A group files may be given: another of this process's groups, as root any other one;
    else its own (then only the modes differ)."""
    own = os.getegid()
    gids = [g for g in os.getgroups() if g != own]
    if os.geteuid() == 0:
        gids += [g.gr_gid for g in grp.getgrall() if g.gr_gid != own]
    for gid in [*gids, own]:
        try:
            return grp.getgrgid(gid).gr_name, gid
        except KeyError:
            continue
    pytest.skip("no named group to use")


@pytest.fixture()
def before_the_group(commissioned: StateDir) -> Iterator[StateDir]:  # noqa: F811
    """The commissioned directory as rvis left it without a group (0750 folders, 0640 files)
    with an OPC UA key, and the process's umask put back afterwards (prepare sets it)."""
    state = commissioned
    state.opcua.mkdir(mode=0o750)
    state.opcua_key.write_text("key\n")
    state.opcua_key.chmod(0o600)
    old = os.umask(0o027)
    yield state
    os.umask(old)


def test_state_check_names_the_strays_and_the_line_that_fixes_them(
    before_the_group: StateDir, tmp_path: Path
) -> None:
    state = before_the_group
    name, gid = target_group()
    assert check(state, 0.0)["group"] is None  # no group asked, none set: nothing to follow
    findings = check(state, 0.0, name)
    assert findings["group"]["strays"] > 0
    (problem,) = findings["problems"]
    assert f"do not follow the operators' group {name}" in problem
    fix = group_fix_command(state, name)
    assert problem.endswith(f"at start), or as root: {fix}")

    copy = StateDir(tmp_path / "copy")  # the line does what it says
    shutil.copytree(state.root, copy.root, symlinks=True)
    subprocess.run(["sh", "-c", group_fix_command(copy, name)], check=True)
    assert group_strays(copy, gid) == []
    assert stat.S_IMODE(copy.opcua_key.stat().st_mode) == 0o600


def test_the_service_gives_the_directory_its_group_at_start(
    before_the_group: StateDir, capsys: pytest.CaptureFixture[str]
) -> None:
    state = before_the_group
    name, gid = target_group()
    prepare(state, name)  # what a service of before this issue did: the folder only
    assert stat.S_IMODE(state.root.stat().st_mode) == 0o2770
    assert main(["state", "check", "--state-dir", str(state.root)]) == 1  # its own group
    assert f"do not follow the operators' group {name}" in capsys.readouterr().out

    with hold_state(state.root, name):
        pass
    assert group_strays(state, gid) == []
    for path in (state.db, state.version_file(1), state.commission / "journal.json"):
        st = path.stat()
        assert st.st_gid == gid and stat.S_IMODE(st.st_mode) == 0o660, path
    assert stat.S_IMODE(state.history.stat().st_mode) == 0o2770
    assert stat.S_IMODE(state.opcua_key.stat().st_mode) == 0o600
    assert main(["state", "check", "--state-dir", str(state.root), "--json"]) == 0
    findings = json.loads(capsys.readouterr().out)
    assert findings["group"] == {"name": name, "strays": 0} and findings["problems"] == []


def as_operator(gid: int, state: StateDir) -> dict[str, Any]:
    """What an operator (another uid, in the group only) reads: `rvis state check`'s
    problems and the TUI's history of applied versions."""

    def read() -> dict[str, Any]:
        seen: dict[str, Any] = {"problems": check(state, 0.0)["problems"]}
        try:
            seen["applied"] = len(HistoryReader(state.db).applied())
        except sqlite3.Error as exc:
            seen["applied"] = str(exc)
        return seen

    return as_user(OPERATOR_UID, [gid], read)


@pytest.mark.skipif(os.geteuid() != 0, reason="reads as another user: needs root")
def test_an_operator_reads_the_history_once_the_service_started_with_the_group(
    before_the_group: StateDir,
) -> None:
    name, gid = target_group()
    base = Path(tempfile.mkdtemp(prefix="rvis-group-"))  # pytest's tmp_path is root's alone
    try:
        base.chmod(0o711)
        state = StateDir(base / "cell")
        shutil.copytree(before_the_group.root, state.root, symlinks=True)
        prepare(state, name)
        before = as_operator(gid, state)
        assert before["applied"] == "unable to open database file", before  # no history
        assert any("rvis.db: unable to open" in p for p in before["problems"])
        assert any(f"do not follow the operators' group {name}" in p for p in before["problems"])
        with hold_state(state.root, name):
            pass
        assert as_operator(gid, state) == {"problems": [], "applied": 1}
    finally:
        shutil.rmtree(base, ignore_errors=True)
