"""Who may do what on the control socket (docs/service-socket.md, "Roles"): the operator
acknowledges, pauses, resumes and asks for a recalibration; the engineer also approves,
rejects, rolls back, resets and shelves (IEC 62443-3-3 SR 1.1/2.1: least privilege, roles
separated).

The role comes from the peer's credentials on the socket (SO_PEERCRED: uid, gid;
SO_PEERGROUPS: its supplementary groups), never from what the request says:

- with no `[service] engineers_group` every peer is an engineer (as before roles existed: the
  socket's mode and the operators' group decide who connects at all);
- root and the service's own user are engineers;
- a peer in `engineers_group` (its primary or a supplementary group) is an engineer;
- any other peer is an operator.

An in-process caller (no socket: the OPC UA server's acknowledgement, tests) passes no
credentials and acts as the service itself. Light: no numerics, usable by `rvis status`.

`NEEDS` is the one list of the socket's commands: the control server, the service's command
queue (app/line/operator.py: a handler `_cmd_<name>` per entry) and `rvis ctl` reach nothing
else. Deny by default: a command missing from it is refused to everyone, engineers and the
service itself included.
"""

from __future__ import annotations

import contextlib
import grp
import os
import pwd
import socket
import struct
from dataclasses import dataclass

from app.errors import InputError

ANYONE, OPERATOR, ENGINEER = "anyone", "operator", "engineer"
#: every command of the socket and the role it needs (anyone: whoever can connect at all);
#: a command not here is refused to everyone
NEEDS = {
    "status": ANYONE,
    "subscribe": ANYONE,
    "pause": OPERATOR,
    "resume": OPERATOR,  # lifting the hold on automatic applies after a rollback: LIFTS_HOLD
    "ack": OPERATOR,
    "recalibrate": OPERATOR,  # its result passes the gates, and in `approve` mode an engineer
    "reset": ENGINEER,
    "approve": ENGINEER,
    "reject": ENGINEER,
    "rollback": ENGINEER,
    "shelve": ENGINEER,
}
#: the role whose `resume` also lets automatic applies go on after a rollback in auto mode
#: (an operator's resume only resumes measuring; an engineer's `approve` lifts it too)
LIFTS_HOLD = ENGINEER
_SO_PEERGROUPS = getattr(socket, "SO_PEERGROUPS", 59)  # Linux >= 4.13
_MAX_GROUPS = 256  # Python's getsockopt reads at most 1024 bytes; more: the group database


@dataclass(frozen=True)
class Peer:
    """The credentials of the process at the other end of the socket."""

    pid: int
    uid: int
    gid: int
    groups: tuple[int, ...]  # primary and supplementary


def peer_credentials(conn: socket.socket) -> Peer | None:
    """SO_PEERCRED and SO_PEERGROUPS of a connected Unix socket (None off Linux)."""
    so_peercred = getattr(socket, "SO_PEERCRED", None)
    if so_peercred is None:
        return None
    creds = conn.getsockopt(socket.SOL_SOCKET, so_peercred, struct.calcsize("3i"))
    pid, uid, gid = struct.unpack("3i", creds)
    groups: tuple[int, ...] | None = None
    with contextlib.suppress(OSError):
        raw = conn.getsockopt(socket.SOL_SOCKET, _SO_PEERGROUPS, 4 * _MAX_GROUPS)
        groups = struct.unpack(f"{len(raw) // 4}I", raw[: len(raw) // 4 * 4])
    if groups is None:
        groups = user_groups(uid)
    return Peer(pid, uid, gid, tuple(sorted({gid, *groups})))


def user_groups(uid: int) -> tuple[int, ...]:
    """The groups the group database gives a user (when the socket cannot say)."""
    try:
        user = pwd.getpwuid(uid)
    except KeyError:
        return ()
    return tuple(os.getgrouplist(user.pw_name, user.pw_gid))


@dataclass(frozen=True)
class Roles:
    """The decision: `Roles.of("rvis-engineers").refusal("approve", uid, groups)`."""

    engineers_group: str = ""
    engineers_gid: int | None = None
    service_uid: int = 0

    @classmethod
    def of(cls, engineers_group: str, service_uid: int | None = None) -> Roles:
        """InputError naming `[service] engineers_group` when there is no such group."""
        uid = os.geteuid() if service_uid is None else service_uid
        if not engineers_group:
            return cls("", None, uid)
        try:
            gid = grp.getgrnam(engineers_group).gr_gid
        except KeyError:
            raise InputError(
                f"no such group {engineers_group!r}", field="[service] engineers_group"
            ) from None
        return cls(engineers_group, gid, uid)

    def role(self, uid: int | None, groups: tuple[int, ...] | None = None) -> str:
        """The role of a peer (uid None: the service's own process)."""
        if self.engineers_gid is None or uid is None or uid in (0, self.service_uid):
            return ENGINEER
        if groups is None:
            groups = user_groups(uid)
        return ENGINEER if self.engineers_gid in groups else OPERATOR

    def refusal(self, cmd: str, uid: int | None, groups: tuple[int, ...] | None = None) -> str:
        """Why the peer may not run `cmd` ("" when it may); deny by default: a command
        missing from `NEEDS` is refused whoever asks."""
        needs = NEEDS.get(cmd)
        if needs is None:
            return f"{cmd} is refused to every role: it is not in the socket's table of commands"
        if needs != ENGINEER or self.role(uid, groups) == ENGINEER:
            return ""
        return (
            f"{cmd} needs the engineer role (group {self.engineers_group}); uid {uid} is an"
            " operator"
        )


__all__ = [
    "ANYONE",
    "ENGINEER",
    "LIFTS_HOLD",
    "NEEDS",
    "OPERATOR",
    "Peer",
    "Roles",
    "peer_credentials",
    "user_groups",
]
