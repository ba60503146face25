"""Another user, for the tests that need root: `as_user(uid, gids, work)` runs `work()` in a
forked child with that uid and those groups (the first the primary) and returns what it
returns, a JSON object, through a pipe (`{"child_error": traceback}` when it raises). The
credentials are numbers: no passwd or group entry is needed."""

from __future__ import annotations

import json
import os
import traceback
from collections.abc import Callable
from typing import Any


def as_user(uid: int, gids: list[int], work: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: it never returns into pytest
        code = 1
        try:
            os.close(r)
            os.setgroups(gids)
            os.setgid(gids[0])
            os.setuid(uid)
            os.write(w, json.dumps(work()).encode())
            code = 0
        except BaseException:
            os.write(w, json.dumps({"child_error": traceback.format_exc()}).encode())
        finally:
            os._exit(code)
    os.close(w)
    with os.fdopen(r, "rb") as pipe:
        data = pipe.read()
    os.waitpid(pid, 0)
    out: dict[str, Any] = json.loads(data)
    return out
