"""Who gets a place among the OPC UA server's connections and sessions (docs/opcua.md
"Isolation"), whatever a peer holds: the caps, and whose place a newcomer takes at each.

Connections: at most MAX_PER_PEER from one peer address and MAX_CONNECTIONS in all. A
connection beyond either cap takes the place of a *pending* connection (one without an activated
session) of that peer, or of the server's peer with the most pending connections: the one heard
from least recently (its last message, else its accept). A client getting on talks at every
step and waits milliseconds for each answer, while a held socket says nothing after its first
bytes, however far they took it (nothing, a Hello, a secure channel, a session not activated):
so a peer that holds and reopens sockets evicts its own, never a client on its way. When the
peer's (or the server's) connections are activated sessions, all but fewer than SPARE pending,
the newcomer is let in beside them instead: at most MAX_PER_PEER + SPARE connections a peer and
MAX_CONNECTIONS + SPARE in all.

Sessions, with the same fairness: at most MAX_PER_PEER activated from one peer address and
MAX_CONNECTIONS in all. A session activated beyond either cap takes the place of the session of
that peer (or of the peer with the most sessions) heard from least recently: an idle session,
not one that is reading or subscribed (a subscriber's Publish requests keep it heard from). So
neither sessions activated and then held idle, from one address or from several, nor sockets
held at any stage lock a fresh client out.

The evicted connection gets Bad_TcpServerTooBusy (app.line.opcua.guard: after a hold).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Protocol

MAX_CONNECTIONS = 64  # a cell's clients: SCADA, MES, a historian, engineering tools
MAX_PER_PEER = 16  # from one address (every client on the cell's computer is one: 127.0.0.1)
SPARE = 4  # pending connections let in beside the activated sessions at a cap


class Seat(Protocol):
    """A connection as admission sees it."""

    host: str
    heard_at: float  # [s, monotonic] its last message (its accept before any)

    def active(self) -> bool:
        """Whether its session is activated."""
        ...

    def evict(self, why: str) -> None:
        """Its place taken (it leaves `clients` at once)."""
        ...


def admit(clients: Sequence[Seat], host: str) -> None:
    """Room for a new connection from `host` among `clients`: at a cap, the pending
    connection heard from least recently evicted (of `host`, or of the peer with the most
    pending connections), unless fewer than SPARE are pending there."""
    mine = [c for c in clients if c.host == host]
    if len(mine) >= MAX_PER_PEER:
        pool, why = mine, f"{host} holds {len(mine)} connections (at most {MAX_PER_PEER} a peer)"
    elif len(clients) >= MAX_CONNECTIONS:
        pool = list(clients)
        why = f"the server holds {len(clients)} connections (at most {MAX_CONNECTIONS})"
    else:
        return
    pending = [c for c in pool if not c.active()]
    if len(pending) < SPARE:
        return  # beside the activated sessions (each session is capped when activated)
    _least_heard(pending, pending).evict(why)


def seat_session(clients: Sequence[Seat], new: Seat) -> None:
    """`new`'s session was just activated: beyond a cap, the session heard from least recently
    of its peer (or of the peer with the most sessions) is evicted."""
    sessions = [c for c in clients if c.active() and c is not new]
    mine = [c for c in sessions if c.host == new.host]
    if len(mine) >= MAX_PER_PEER:
        pool = mine
        why = f"{new.host} holds {len(mine)} activated sessions (at most {MAX_PER_PEER} a peer)"
    elif len(sessions) >= MAX_CONNECTIONS:
        pool = sessions
        why = f"the server holds {len(sessions)} activated sessions (at most {MAX_CONNECTIONS})"
    else:
        return
    _least_heard(pool, sessions).evict(why)


def _least_heard(pool: Sequence[Seat], counted: Sequence[Seat]) -> Seat:
    """Of `pool`, the one of the peer with the most of `counted` heard from least recently."""
    per_host = Counter(c.host for c in counted)
    return min(pool, key=lambda c: (-per_host[c.host], c.heard_at))
