"""Roles through the real socket of a real service (issue 30 item 11): processes running as
other users, in the operators' group or in both groups, ask a running `rvis run --sim` for
commands; the service decides from their credentials (SO_PEERCRED, SO_PEERGROUPS), refuses
an operator what needs an engineer with the role it needs, and audits the refusal with the
peer's uid. Needs root (it creates two groups for the test)."""

from __future__ import annotations

import grp
import json
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.line.roles import NEEDS
from tests.ops.conftest import CELL, ServiceProcess, count
from tests.peers import as_user

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("groupadd") is None, reason="creates groups: needs root"
)
OPERATOR_UID, ENGINEER_UID = 54321, 54322  # no passwd entries needed: credentials are numbers


@pytest.fixture
def groups() -> Iterator[tuple[str, str]]:
    names = (f"rvt{os.getpid()}op", f"rvt{os.getpid()}en")
    for name in names:
        subprocess.run(["groupadd", name], check=True, capture_output=True)
    try:
        yield names
    finally:
        for name in names:
            subprocess.run(["groupdel", name], capture_output=True)


@pytest.fixture
def base() -> Iterator[Path]:
    """A folder other users can traverse (pytest's tmp_path is root's alone)."""
    path = Path(tempfile.mkdtemp(prefix="rvis-roles-"))
    path.chmod(0o711)
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def as_peer(sock: Path, uid: int, gids: list[int], cmd: str, **args: Any) -> dict[str, Any]:
    """One request from a child process running as `uid` in `gids` (the first its primary)."""

    def request() -> dict[str, Any]:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(60)
            s.connect(str(sock))
            s.sendall(json.dumps({"id": 1, "cmd": cmd, "args": args}).encode() + b"\n")
            reply: dict[str, Any] = json.loads(s.makefile("rb").readline())
        return reply

    return as_user(uid, gids, request)


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_an_operator_is_refused_the_engineers_commands_and_the_refusal_is_audited(
    groups: tuple[str, str], base: Path
) -> None:
    ops, eng = groups
    cell = base / "cell.toml"
    cell.write_text(
        CELL.replace(
            "[service]", f'[service]\noperators_group = "{ops}"\nengineers_group = "{eng}"'
        ),
        encoding="utf-8",
    )
    state = base / "state"
    ops_gid, eng_gid = grp.getgrnam(ops).gr_gid, grp.getgrnam(eng).gr_gid
    svc = ServiceProcess(state, cell)
    try:
        svc.wait_ready()
        sock = state / "rvis.sock"
        operator = [ops_gid]
        assert as_peer(sock, OPERATOR_UID, operator, "pause")["ok"]
        refused = as_peer(sock, OPERATOR_UID, operator, "rollback", version=1)
        assert refused["ok"] is False and refused["role"] == "engineer"
        assert "rollback needs the engineer role" in refused["error"]
        assert f"uid {OPERATOR_UID} is an operator" in refused["error"]
        assert as_peer(sock, OPERATOR_UID, operator, "resume")["ok"]
        # the same command by an engineer (supplementary group) passes the role check (version
        # 1 may be in force still: then refused as nothing to roll back, issue 39 item 5)
        done = as_peer(sock, ENGINEER_UID, [ops_gid, eng_gid], "rollback", version=1)
        assert "role" not in done and (done["ok"] or "in force already" in done["error"]), done
        audit = "SELECT COUNT(*) FROM actions WHERE cmd = 'rollback'"
        assert count(state / "rvis.db", f"{audit} AND ok = 0 AND uid = {OPERATOR_UID}") == 1
        assert count(state / "rvis.db", f"{audit} AND uid = {ENGINEER_UID}") == 1
        # every command of the table, as the operator (issue 39 item 4): the engineers' ones
        # refused with the role, none unknown; one missing from the table refused
        for cmd, needs in NEEDS.items():
            if cmd != "subscribe":
                reply = as_peer(sock, OPERATOR_UID, operator, cmd)
                assert (reply.get("role") == "engineer") == (needs == "engineer"), (cmd, reply)
                assert "unknown command" not in str(reply.get("error")), (cmd, reply)
        assert as_peer(sock, OPERATOR_UID, operator, "frobnicate")["ok"] is False
    finally:
        assert svc.stop() == 0
