"""The applied parameters: `state_dir/params/current.json` and a numbered history.

Every version is written once to `params/history/NNNN.json` and then made current by replacing
`current.json` atomically (temporary file in the same directory, fsync, os.replace, fsync of the
directory): after a crash at any moment `current.json` is one complete version of the history.
A rollback makes an earlier history file current again. Documents are app.formats.params' parameters
JSON (readable by `app.formats.params.from_json`) with one more key, `history_version`.

Naming a store reads and changes nothing (read-only callers use it too); `apply` creates the
folders it writes to, and only the service, which holds the state directory's lock, removes the
temporary files a crash left (`remove_stale`). The names are app/line/statedir.py's.

`first_in_force` is the one rule by which a state directory gets its first version: the
service's start on a new directory and the commissioning's last step both use it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.formats.files import dumps_json, replace_atomically
from app.formats.params import carried_from_json, from_json
from app.line.statedir import StateDir
from calib.model import SystemModel

if TYPE_CHECKING:
    from app.line.store import Store
    from drivers.clock import Clock

F64 = NDArray[np.float64]
#: the provenance of a new state directory's first version made of the service's starting
#: parameters (nominal, or `rvis run --params`): no calibration of this cell (app.line.startup
#: writes it, app.line.uncommissioned reads it)
INITIAL_SOURCE = "initial parameters"


def atomic_write_json(path: Path, doc: dict[str, Any]) -> None:
    """Write `doc` to `path` so that readers see the old file or the new one, never a part."""
    replace_atomically(path, (dumps_json(doc, indent=1) + "\n").encode("utf-8"))


class ParamsStore:
    """`state_dir/params`: apply a document as a new version, read the current one, roll back."""

    def __init__(self, state_dir: str | Path) -> None:
        self.state = StateDir(state_dir)
        self.dir = self.state.params
        self.history = self.state.history
        self.current_path = self.state.current

    def remove_stale(self) -> int:
        """Remove the temporary files a crash left before os.replace (the service, at start,
        holding the lock); how many."""
        stale = self.state.stale_temporaries()
        for path in stale:
            path.unlink(missing_ok=True)
        return len(stale)

    def version_path(self, version: int) -> Path:
        """The history file of a version."""
        return self.state.version_file(version)

    def versions(self) -> list[int]:
        return self.state.versions()

    def apply(self, doc: dict[str, Any]) -> int:
        """Write `doc` as the next history version and make it current; returns the version."""
        self.history.mkdir(parents=True, exist_ok=True)
        version = max(self.versions(), default=0) + 1
        doc = {**doc, "history_version": version}
        atomic_write_json(self.version_path(version), doc)
        atomic_write_json(self.current_path, doc)
        return version

    def rollback(self, version: int) -> int:
        """Make history version `version` current again (InputError if there is none)."""
        path = self.version_path(version)
        if not path.is_file():
            raise InputError(f"no parameters version {version}", file=path)
        atomic_write_json(self.current_path, json.loads(path.read_text(encoding="utf-8")))
        return version

    def current_version(self) -> int | None:
        return self.state.current_version()

    def current(self, target: SystemModel | None = None) -> tuple[int, SystemModel, F64] | None:
        """(version, model, parameter vector) in force, or None before the first apply; with
        `target`, as a service that identifies `target` uses them (a rigid version carried
        at its calibration temperature: `carried_from_json`)."""
        version = self.current_version()
        if version is None:
            return None
        if target is not None:
            return version, *carried_from_json(target, self.current_path)
        model, x = from_json(self.current_path)
        return version, model, x

    def current_document(self) -> dict[str, Any] | None:
        """The document in force as written (its identification's covariance included)."""
        if not self.current_path.exists():
            return None
        doc = json.loads(self.current_path.read_text(encoding="utf-8"))
        return doc if isinstance(doc, dict) else None

    def document(self, version: int) -> dict[str, Any] | None:
        """Version `version`'s document as written (None: none, or not readable)."""
        try:
            doc = json.loads(self.version_path(version).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) else None


def first_in_force(
    params: ParamsStore,
    store: Store,
    doc: dict[str, Any],
    source: str,
    clock: Clock,
    written: int | None = None,
) -> int:
    """Put a state directory's first parameters version in force: `doc` written as the next
    version and made current, then the database's applied row for it (no calibration, no
    user) at `clock`'s time, unless the database records one already. `written`: the version
    `current.json` holds already (a run killed after writing it, before the database learnt
    it), only recorded. Returns the version in force."""
    version = params.apply(doc) if written is None else written
    if not store.applied():
        store.add_applied(clock.time(), version, None, source, None)
    return version


#: the applied row's source of a version a maintenance procedure put in force (app/maintain/):
#: the service's first start after it begins afresh on it (Service._after_maintenance)
MAINTENANCE_SOURCE = "maintenance"


def hand_over(params: ParamsStore, store: Store, doc: dict[str, Any], t: float) -> int:
    """A maintenance procedure's version in force: `doc` written as the next version and made
    current, and recorded as applied at time t with `MAINTENANCE_SOURCE` in one transaction;
    a run killed between the two finds current.json ahead of the database, as after a kill
    in the service's own apply (completed at the service's start). Returns the version."""
    version = params.apply(doc)
    store.add_applied(t, version, None, MAINTENANCE_SOURCE, None)
    return version
