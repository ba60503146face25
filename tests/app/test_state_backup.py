"""`rvis state backup|restore|check` walk the state directory as app/line/statedir.py lays it
out (issue 30 item 3): a commissioned cell's `cell.toml`, `sensor.toml`, `plan.json` and
`commission/` travel with the backup, and `state check` says when the files the commissioning
wrote are missing (the service would run with the design sensor model). Naming the parameters
(`ParamsStore`) creates and cleans nothing: only the service does."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from app.commands.state_backup import backup, restore
from app.commands.state_check import check
from app.formats.params import plain_document
from app.line.params_store import ParamsStore
from app.line.statedir import StateDir
from app.line.store import Store

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture()
def commissioned(tmp_path: Path, request: pytest.FixtureRequest) -> StateDir:
    """A state directory as `rvis commission` leaves it (app/commission/ready.py)."""
    from app.config import load_cell

    state = StateDir(tmp_path / "cell")
    state.root.mkdir(mode=0o750)
    old = os.umask(0o027)  # as the service's prepare() sets it
    request.addfinalizer(lambda: os.umask(old))
    model = load_cell(None).model()
    ParamsStore(state.root).apply(plain_document(model, model.nominal_x(), "commissioning"))
    store = Store(state.db)
    store.add_applied(1.8e9, 1, None, "commissioning", None)
    store.close()
    state.plan.write_text('{"plan": 1}\n')
    state.cell.write_text("# the commissioned cell\n")
    state.sensor.write_text("# the calibrated sensor\n")
    (state.commission / "sensor").mkdir(parents=True)
    (state.commission / "journal.json").write_text("{}\n")
    (state.commission / "sensor" / "board_00.png").write_bytes(b"png")
    return state


def test_a_backup_carries_the_commissioned_files_and_restores_them(
    commissioned: StateDir, tmp_path: Path
) -> None:
    manifest = backup(commissioned, tmp_path / "backup")
    files = set(manifest["files"])
    assert {"cell.toml", "sensor.toml", "plan.json", "params/current.json"} <= files
    assert {"params/history/0001.json", "commission/journal.json"} <= files
    assert "commission/sensor/board_00.png" in files
    restored = StateDir(tmp_path / "restored")
    restore(tmp_path / "backup", restored)
    for path in commissioned.carried():
        rel = path.relative_to(commissioned.root)
        assert (restored.root / rel).read_bytes() == path.read_bytes(), rel
    findings = check(restored, 0.0)
    assert findings["problems"] == [] and findings["commissioned"]["by_commissioning"]


def test_a_restored_cell_file_names_the_directory_it_was_restored_into(
    commissioned: StateDir, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The cell file `rvis commission` wrote names its state directory (`[service]
    state_dir`): restored elsewhere, it named the old one, so that a command given `--cell
    NEW/cell.toml` read or wrote the old directory. Restore makes it name the new one (the rest
    of the file as it was), and check says when a cell file names another directory."""
    from app.commands.cli import main
    from app.config import load_cell
    from app.config.write import dumps_cell

    cfg = load_cell(None)
    cfg = dataclasses.replace(
        cfg, service=dataclasses.replace(cfg.service, state_dir=str(commissioned.root.resolve()))
    )
    commissioned.cell.write_text(dumps_cell(cfg, "written by rvis commission from cell.toml"))
    assert check(commissioned, 0.0)["problems"] == []
    backup(commissioned, tmp_path / "backup")
    restored = StateDir(tmp_path / "elsewhere")
    argv = ["state", "restore", str(tmp_path / "backup"), "--state-dir", str(restored.root)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    here = restored.root.resolve()
    assert f"cell.toml: [service] state_dir {commissioned.root.resolve()} -> {here}" in out
    again = load_cell(restored.cell)
    assert Path(again.service.state_dir) == here
    moved = dataclasses.replace(cfg, service=dataclasses.replace(cfg.service, state_dir=str(here)))
    assert dumps_cell(again) == dumps_cell(moved)  # the rest of the file as it was
    text = restored.cell.read_text()
    assert text.startswith("# written by rvis commission from cell.toml\n# restored by rvis")
    assert check(restored, 0.0)["problems"] == []
    # a cell file naming another directory (moved by hand): check names it
    commissioned.cell.write_text(dumps_cell(cfg).replace(str(commissioned.root.resolve()), "/x"))
    problems = check(commissioned, 0.0)["problems"]
    assert any("state_dir names /x, not this directory" in p for p in problems)


def test_check_names_a_missing_commissioned_sensor_file(commissioned: StateDir) -> None:
    assert check(commissioned, 0.0)["problems"] == []
    commissioned.sensor.unlink()
    commissioned.cell.unlink()
    problems = check(commissioned, 0.0)["problems"]
    assert len(problems) == 2
    assert any("sensor.toml: missing, although rvis commission wrote it" in p for p in problems)
    assert any("cell.toml: missing" in p for p in problems)


def test_a_directory_the_commissioning_did_not_make_needs_no_cell_file(tmp_path: Path) -> None:
    state = StateDir(tmp_path / "cell")
    state.root.mkdir()
    Store(state.db).close()
    findings = check(state, 0.0)
    assert findings["commissioned"] == {"by_commissioning": False}
    assert not any("rvis commission" in p for p in findings["problems"])


def test_reading_the_parameters_creates_and_cleans_nothing(commissioned: StateDir) -> None:
    stale = commissioned.params / ".current.json.abc.tmp"
    stale.write_text("{")
    assert ParamsStore(commissioned.root).current_version() == 1
    check(commissioned, 0.0)
    assert stale.exists()
    nowhere = StateDir(commissioned.root.parent / "nowhere")
    assert ParamsStore(nowhere.root).current() is None and nowhere.versions() == []
    assert not nowhere.root.exists()
    assert ParamsStore(commissioned.root).remove_stale() == 1 and not stale.exists()


def test_state_check_cli_leaves_temporary_files_alone(commissioned: StateDir) -> None:
    state = commissioned.root
    stale = commissioned.history / ".0002.json.abc.tmp"
    stale.write_text("{")
    done = subprocess.run(
        [sys.executable, "-m", "app", "state", "check", "--json", "--state-dir", str(state)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert json.loads(done.stdout)["commissioned"] == {"by_commissioning": True, "missing": []}
    assert stale.exists()


def test_backup_prints_words_and_json_on_request(commissioned: StateDir, tmp_path: Path) -> None:
    """Issue 30 item 10: words for a person; the manifest with --json."""

    def backup_cli(dest: Path, *more: str) -> subprocess.CompletedProcess[str]:
        argv = ["state", "backup", str(dest), "--state-dir", str(commissioned.root), *more]
        return subprocess.run(
            [sys.executable, "-m", "app", *argv], cwd=ROOT, capture_output=True, text=True
        )

    words = backup_cli(tmp_path / "b1")
    assert words.returncode == 0, words.stderr
    lines = words.stdout.splitlines()
    assert lines[0].startswith(f"backed up {commissioned.root.resolve()} to {tmp_path / 'b1'}")
    assert "integrity ok, measurements 0 ok, 0 rejected" in lines[1]
    assert lines[2] == "  parameters  version 1 in force, 1 in the history"
    assert lines[3].startswith("  files       ") and "backup.json" in lines[3]
    as_json = backup_cli(tmp_path / "b2", "--json")
    manifest = json.loads(as_json.stdout)
    assert manifest["applied_version"] == 1 and "sensor.toml" in manifest["files"]
