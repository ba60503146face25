"""The simulated cell a state directory runs, kept as a commissioned directory keeps it: `rvis
run --sim` on a directory made by an earlier `rvis run --sim` runs the same cell (its seed) the
same way (geometric or rendered), as the history it made (parameters, charts, the world's
time) belongs to that cell. A commissioned directory's cell file records both (`[simulation]
seed`, `geometric`, app/commission/ready.py); a directory the simulated line made has
`simulation.json` (app.line.statedir `StateDir.simulation`), written by its first run:

    {"seed": 44, "geometric": true, "written_by": "rvis run --sim"}

    seed, geometric = simulated_world(state, args.seed, args.geometric, default)
    record_world(state, seed, geometric)      # under the state's lock, a new directory only

Another `--seed` is another cell: refused in one line (exit 2); `--geometric` measures a
rendered directory's cell the fast way (the same world).
"""

from __future__ import annotations

from typing import Any

from app.errors import InputError
from app.line.statedir import StateDir

WRITTEN_BY = "rvis run --sim"


def simulated_world(
    state: StateDir, seed: int | None, geometric: bool, default: tuple[int, bool]
) -> tuple[int, bool]:
    """(seed, geometric) of `rvis run --sim` on `state`, a directory not commissioned: its
    record's (--geometric: the same cell measured the fast way), else `default` (--seed or
    the cell file's, --geometric or the cell file's). Another seed than the record's:
    InputError, one line."""
    record = read_world(state)
    if record is None:
        return default
    own = int(record["seed"])
    if seed is not None and seed != own:
        path = "--geometric " if record["geometric"] else ""
        raise InputError(
            f"this directory's simulated cell is seed {own} (made by `rvis run --sim {path}--seed"
            f" {own}`): --seed {seed} is another cell (leave --seed out, or use another"
            " --state-dir)",
            file=state.simulation,
            field="seed",
        )
    return own, bool(geometric or record["geometric"])


def read_world(state: StateDir) -> dict[str, Any] | None:
    """The directory's record (None: none); InputError naming the file when it is damaged."""
    from app.formats.files import read_json

    try:
        if not state.simulation.is_file():
            return None
    except OSError:  # a directory this user cannot read: the service's start says so
        return None
    doc = read_json(state.simulation)
    seed, geometric = doc.get("seed"), doc.get("geometric")
    if not (isinstance(seed, int) and seed >= 0 and isinstance(geometric, bool)):
        raise InputError(
            "not a record of the simulated cell (seed: an integer >= 0, geometric: true or false)",
            file=state.simulation,
        )
    return doc


def record_world(state: StateDir, seed: int, geometric: bool) -> None:
    """The record of a new directory's simulated cell (none when the directory has a history
    or a commissioned cell file: what made those is not known here, or says it itself)."""
    from app.formats.files import write_json

    if state.db.exists() or state.cell.exists() or state.simulation.exists():
        return
    write_json(state.simulation, {"seed": seed, "geometric": geometric, "written_by": WRITTEN_BY})
