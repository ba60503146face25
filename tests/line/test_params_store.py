"""The applied parameters file: apply, history, rollback, and atomicity under kill -9."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.config import load_cell
from app.errors import InputError
from app.formats.params import from_json, plain_document
from app.line.params_store import ParamsStore, first_in_force
from app.line.store import Store
from calib.model import INDEX


def _doc(offset_mm: float) -> dict[str, object]:
    model = load_cell(None).model()
    x = model.nominal_x()
    x[INDEX[next(iter(INDEX))]] += offset_mm
    return plain_document(model, x, f"offset {offset_mm}")


def test_apply_numbers_versions_and_current_reads_back(tmp_path: Path) -> None:
    store = ParamsStore(tmp_path)
    assert store.current() is None
    v1, v2 = store.apply(_doc(0.0)), store.apply(_doc(1.5))
    assert (v1, v2) == (1, 2) and store.versions() == [1, 2]
    current = store.current()
    assert current is not None
    version, model, x = current
    assert version == 2
    assert x[0] - model.nominal_x()[0] == pytest.approx(1.5)
    _, x_file = from_json(
        tmp_path / "params" / "history" / "0002.json"
    )  # app.formats.params reads it
    assert np.array_equal(x_file, x)


def test_rollback_makes_an_earlier_version_current(tmp_path: Path) -> None:
    store = ParamsStore(tmp_path)
    for k in range(3):
        store.apply(_doc(float(k)))
    assert store.rollback(1) == 1
    current = store.current()
    assert current is not None and current[0] == 1
    assert current[2][0] == pytest.approx(current[1].nominal_x()[0])
    assert store.apply(_doc(9.0)) == 4  # a new version after a rollback is numbered on
    with pytest.raises(InputError):
        store.rollback(17)


def test_stale_temporary_files_are_removed_by_the_writer_only(tmp_path: Path) -> None:
    store = ParamsStore(tmp_path)
    store.apply(_doc(0.0))
    stale = store.dir / ".current.json.abc.tmp"
    stale.write_text("{", encoding="utf-8")
    ParamsStore(tmp_path)  # a reader: cleans nothing
    assert stale.exists()
    assert ParamsStore(tmp_path).remove_stale() == 1  # the service, at start
    assert not stale.exists()


APPLIER = """
import sys
from tests.line.test_params_store import _doc
from app.line.params_store import ParamsStore, first_in_force
from app.line.store import Store
store = ParamsStore(sys.argv[1])
k = 0
while True:
    print(store.apply(_doc(float(k % 7))), flush=True)
    k += 1
"""


@pytest.mark.parametrize("n_applies", [1, 5, 23])
def test_kill_9_during_apply_leaves_one_complete_version(tmp_path: Path, n_applies: int) -> None:
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen(
        [sys.executable, "-c", APPLIER, str(tmp_path)], stdout=subprocess.PIPE, cwd=root, text=True
    )
    assert proc.stdout is not None
    acked = [int(proc.stdout.readline()) for _ in range(n_applies)]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    store = ParamsStore(tmp_path)
    current = json.loads(store.current_path.read_text(encoding="utf-8"))  # complete JSON
    version = current["history_version"]
    assert version >= acked[-1]  # never older than what was acknowledged
    history = json.loads((store.history / f"{version:04d}.json").read_text(encoding="utf-8"))
    assert history == current
    assert store.current() is not None


class _Stopped:
    """A clock standing at one time (first_in_force reads only `time`)."""

    def __init__(self, t: float) -> None:
        self.t = t

    def monotonic(self) -> float:
        return self.t

    def time(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:  # sleep-ok: a fake clock, time advances
        self.t += seconds

    def wait(self, event: object, seconds: float) -> bool:
        self.t += seconds
        return False


def test_the_first_version_in_force_is_recorded_at_the_clock_given(tmp_path: Path) -> None:
    """One rule for the first version (the service's start, the commissioning's last step):
    written as version 1, recorded once at the caller's clock; a run killed after writing it
    is only recorded; a run after the record changes nothing."""
    params, store = ParamsStore(tmp_path), Store(tmp_path / "rvis.db")
    try:
        assert first_in_force(params, store, _doc(0.0), "commissioning", _Stopped(1234.5)) == 1
        rows = [(r["t"], r["version"], r["source"]) for r in store.applied()]
        assert rows == [(1234.5, 1, "commissioning")]
        assert params.versions() == [1]
        again = first_in_force(params, store, _doc(0.0), "commissioning", _Stopped(99.0), 1)
        assert again == 1 and params.versions() == [1] and len(store.applied()) == 1
    finally:
        store.close()
    fresh = tmp_path / "killed"  # current.json written, the database not told yet
    params = ParamsStore(fresh)
    written = params.apply(_doc(0.0))
    store = Store(fresh / "rvis.db")
    try:
        assert first_in_force(params, store, _doc(1.0), "initial", _Stopped(7.0), written) == 1
        assert params.versions() == [1]
        assert [(r["t"], r["version"]) for r in store.applied()] == [(7.0, 1)]
    finally:
        store.close()
