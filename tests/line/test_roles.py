"""Roles on the control socket (issue 30 item 11): the operator acknowledges, pauses, resumes
and asks for a recalibration; approve, reject, roll back, reset and shelve need the engineer
role, decided from the peer's credentials (app/line/roles.py)."""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Any

import pytest

from app.errors import InputError
from app.line.control import ControlClient, ControlServer
from app.line.operator import Operator
from app.line.roles import ANYONE, ENGINEER, NEEDS, OPERATOR, Roles, peer_credentials
from tests.line.helpers import make_line

ROLES = Roles("rvis-engineers", engineers_gid=4242, service_uid=998)


def test_without_an_engineers_group_everyone_is_an_engineer() -> None:
    roles = Roles.of("")
    assert roles.role(12345, ()) == ENGINEER
    assert all(roles.refusal(cmd, 12345, ()) == "" for cmd in NEEDS)


def test_the_engineers_group_decides_and_root_and_the_service_are_engineers() -> None:
    assert ROLES.role(12345, (100, 4242)) == ENGINEER
    assert ROLES.role(12345, (100,)) == OPERATOR
    assert ROLES.role(0, ()) == ENGINEER and ROLES.role(998, ()) == ENGINEER
    assert ROLES.role(None) == ENGINEER  # in-process: the service itself


def test_an_operator_is_refused_what_needs_an_engineer_with_the_role_named() -> None:
    for cmd in ("pause", "resume", "ack", "recalibrate", "status"):
        assert ROLES.refusal(cmd, 12345, (100,)) == ""
    for cmd in ("approve", "reject", "rollback", "reset", "shelve"):
        why = ROLES.refusal(cmd, 12345, (100,))
        assert why.startswith(f"{cmd} needs the engineer role (group rvis-engineers)")
        assert "uid 12345 is an operator" in why
        assert ROLES.refusal(cmd, 12345, (4242,)) == ""


def test_an_unknown_engineers_group_names_the_setting() -> None:
    with pytest.raises(InputError, match=r"engineers_group.*no such group|no such group"):
        Roles.of("no-such-group-rvis-test")


def test_the_peer_credentials_are_the_connecting_process_s() -> None:
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    with a, b:
        peer = peer_credentials(a)
    assert peer is not None
    assert (peer.pid, peer.uid) == (os.getpid(), os.geteuid())
    assert set(os.getgroups()) | {os.getegid()} <= set(peer.groups)


def test_every_command_has_its_role_in_the_one_table_and_a_handler() -> None:
    """Issue 39 item 4: the table is the list of commands (the operator's handlers, the
    socket's status and subscribe), each with a known role."""
    handlers = {n.removeprefix("_cmd_") for n in dir(Operator) if n.startswith("_cmd_")}
    assert handlers | {"status", "subscribe"} == set(NEEDS)
    assert set(NEEDS.values()) <= {ANYONE, OPERATOR, ENGINEER}


def test_a_command_missing_from_the_table_is_refused_to_everyone(tmp_path: Path) -> None:
    """Deny by default: a handler added without its row in NEEDS runs for nobody, not even
    the service itself or an engineer."""

    class Extended(Operator):
        def _cmd_frobnicate(self, args: dict[str, Any], uid: int | None) -> dict[str, Any]:
            raise AssertionError("a command missing from the table ran")

    ln = make_line(tmp_path)
    try:
        op = Extended(ln.service)
        for uid, groups in ((None, None), (0, ()), (12345, (4242,))):
            reply = op.request("frobnicate", {}, uid, groups).result(0)
            assert reply == {"ok": False, "error": "unknown command 'frobnicate'"}
        assert ROLES.refusal("frobnicate", None).startswith("frobnicate is refused to every role")
    finally:
        ln.close()


def test_the_socket_walks_every_command_and_an_operator_gets_what_the_table_allows(
    tmp_path: Path,
) -> None:
    """Every command the socket accepts, through the socket (this process: an engineer) and
    with an operator's credentials as the socket passes them: the engineers' ones refused
    with the role they need, the others run (whatever their own answer)."""
    ln = make_line(tmp_path)
    path = tmp_path / "rvis.sock"
    try:
        with ControlServer(ln.service, path):
            ln.start().wait(lambda e: e["event"] == "state" and e["to"] == "idle")
            with ControlClient(path) as client:
                for cmd in NEEDS:
                    if cmd == "subscribe":
                        continue  # streams events until closed: below
                    reply = client.request(cmd)
                    assert "role" not in reply and "unknown command" not in str(reply), cmd
                assert client.request("frobnicate")["error"] == "unknown command 'frobnicate'"
            with ControlClient(path) as client:
                assert client.request("subscribe") == {"id": 1, "ok": True}
            ln.service.roles = ROLES
            for cmd, needs in NEEDS.items():
                if cmd == "subscribe":
                    continue
                reply = ln.service.request(cmd, {}, 12345, (100,)).result(30)
                assert (reply.get("role") == ENGINEER) == (needs == ENGINEER), (cmd, reply)
    finally:
        ln.close()
