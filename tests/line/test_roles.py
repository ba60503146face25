"""Roles on the control socket (issue 30 item 11): the operator acknowledges, pauses, resumes
and asks for a recalibration; approve, reject, roll back, reset and shelve need the engineer
role, decided from the peer's credentials (app/line/roles.py)."""

from __future__ import annotations

import os
import socket

import pytest

from app.errors import InputError
from app.line.roles import ENGINEER, NEEDS, OPERATOR, Roles, peer_credentials

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
