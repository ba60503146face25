"""The parameter history past version 9999 (issue 39 item 3): a version file's name has at
least four digits and is read back by the same rule, so `10000.json` is a version, the next
apply is 10001 (not 10000 again, overwriting it), versions are ordered by number, and
rollback, `rvis state backup|restore|check` reach every one of them. The history is written
directly (a template per file, no fsync): a cell with 10,001 versions in well under a second."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from app.commands.state_backup import backup, restore
from app.commands.state_check import check
from app.config import load_cell
from app.formats.files import dumps_json
from app.formats.params import plain_document
from app.line.params_store import ParamsStore
from app.line.statedir import StateDir, version_name, version_of
from app.line.store import Store

T0 = 1.8e9  # [s] Unix time of the first version
PERIOD_S = 1800.0  # a recalibration every half hour


def _document(note: str) -> dict[str, object]:
    model = load_cell(None).model()
    return plain_document(model, model.nominal_x(), note)


def write_history(state: StateDir, n: int) -> None:
    """Versions 1..n as the service leaves them: each history file, `current.json` holding
    version n and the database's applied rows, written directly (no apply, no fsync)."""
    state.history.mkdir(parents=True)
    text = dumps_json({**_document("past"), "history_version": -1}, indent=1) + "\n"
    head, _, tail = text.rpartition("-1")
    for v in range(1, n + 1):
        state.version_file(v).write_text(f"{head}{v}{tail}", encoding="utf-8")
    state.current.write_bytes(state.version_file(n).read_bytes())
    store = Store(state.db)
    with store.batch():
        for v in range(1, n + 1):
            store.add_applied(T0 + PERIOD_S * v, v, None, "auto", None)
    store.close()


@pytest.fixture()
def umask() -> object:
    old = os.umask(0o027)  # as the service's prepare() sets it
    yield
    os.umask(old)


def test_names_and_reading_agree_past_9999() -> None:
    for v in (1, 7, 999, 9999, 10000, 10001, 123456):
        assert version_of(version_name(v)) == v
    assert version_name(7) == "0007.json" and version_name(10000) == "10000.json"
    for name in ("7.json", "00007.json", "0000.json", "12a4.json", "0007.json.tmp", "0007"):
        assert version_of(name) is None, name


def test_9999_then_10000_then_10001_roll_back_back_up_restore(
    tmp_path: Path, umask: object
) -> None:
    state = StateDir(tmp_path / "cell")
    write_history(state, 9999)
    params = ParamsStore(state.root)
    assert params.current_version() == 9999
    assert params.apply(_document("a")) == 10000
    assert params.apply(_document("b")) == 10001  # not 10000 again over the last
    store = Store(state.db)
    store.add_applied(T0 + PERIOD_S * 10001, 10001, None, "auto", None)
    store.close()
    versions = params.versions()
    assert len(versions) == 10001 and versions[-4:] == [9998, 9999, 10000, 10001]
    assert json.loads(state.version_file(10000).read_text())["history_version"] == 10000
    assert params.rollback(10000) == 10000 and params.current_version() == 10000
    assert params.rollback(10001) == 10001 and params.current_version() == 10001
    assert check(state, 0.0)["problems"] == []

    manifest = backup(state, tmp_path / "backup")
    assert manifest["history_versions"] == 10001 and manifest["applied_version"] == 10001
    assert {"params/history/9999.json", "params/history/10001.json"} <= set(manifest["files"])
    restored = StateDir(tmp_path / "restored")
    restore(tmp_path / "backup", restored)
    assert restored.versions() == versions
    assert restored.current.read_bytes() == state.version_file(10001).read_bytes()
    findings = check(restored, 0.0)
    assert findings["problems"] == []
    assert findings["parameters"] == {"history_versions": 10001, "current_version": 10001}
    assert ParamsStore(restored.root).apply(_document("c")) == 10002
