"""The state directory's layout has one home, app/line/statedir.py (issue 33 item 1): no other
module of app/ (or rvis/) spells one of its file names, joins one of its folder names onto a
path, or writes a parameters version's file name (`{version:04d}.json`). Checked on the source
(AST string constants), like tests/test_layers.py."""

from __future__ import annotations

import ast
from pathlib import Path

from app.commission import files
from app.line import statedir

ROOT = Path(__file__).resolve().parents[1]
HOME = ROOT / "app" / "line" / "statedir.py"
NAMES = {v for k, v in vars(statedir).items() if k.endswith("_NAME") and isinstance(v, str)}
FOLDERS = {v for k, v in vars(statedir).items() if k.endswith("_DIR") and isinstance(v, str)}


def spelled(path: Path) -> list[str]:
    """Where `path` spells a state directory's name: 'line: what'."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and node.value in NAMES:
            found.append(f"{node.lineno}: {node.value!r}")
        elif (
            isinstance(node, ast.BinOp)
            and isinstance(node.op, ast.Div)
            and isinstance(node.right, ast.Constant)
            and node.right.value in FOLDERS
        ):
            found.append(f"{node.lineno}: / {node.right.value!r}")
        elif isinstance(node, ast.JoinedStr):
            for k, part in enumerate(node.values[:-1]):
                spec = part.format_spec if isinstance(part, ast.FormattedValue) else None
                after = node.values[k + 1]
                if (
                    spec is not None
                    and "04d" in ast.unparse(spec)
                    and isinstance(after, ast.Constant)
                    and str(after.value).startswith(".json")
                ):
                    found.append(f"{node.lineno}: a version file name")
    return found


def test_the_names_are_known() -> None:
    assert {"rvis.db", "rvis.sock", "cell.toml", "sensor.toml", "current.json"} <= NAMES
    assert {"params", "history", "commission", "opcua"} <= FOLDERS


def test_only_statedir_spells_the_state_directory() -> None:
    where = {
        str(p.relative_to(ROOT)): hits
        for top in ("app", "rvis")
        for p in sorted((ROOT / top).rglob("*.py"))
        if p != HOME and (hits := spelled(p))
    }
    assert where == {}


def test_the_checker_sees_each_kind(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text(
        'db = root / "rvis.db"\nh = root / "params" / "history"\nf = f"{v:04d}.json"\n',
        encoding="utf-8",
    )
    assert len(spelled(bad)) == 4


COMMISSION_HOME = ROOT / "app" / "commission" / "files.py"
COMMISSION_NAMES = {
    v
    for k, v in vars(files).items()
    if k.endswith(("_FILE", "_DIR")) and isinstance(v, str) and v not in NAMES
}
#: the same name for another folder's file: the demo's report folder has its own params.json
OTHER_FOLDERS = {("app/sim/demo.py", "params.json")}


def constants(path: Path, names: set[str]) -> set[tuple[str, str]]:
    """(module, name) for each string constant of `path` that is one of `names`."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    rel = str(path.relative_to(ROOT))
    return {
        (rel, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names
    }


def test_only_the_commissioning_files_module_spells_its_files() -> None:
    """The commissioning folder's file names (issue 33 item 6) are spelled in
    app/commission/files.py only."""
    assert {"params.json", "targets.csv", "stripe.json", "acceptance.csv"} <= COMMISSION_NAMES
    where = {
        hit
        for top in ("app", "rvis")
        for p in sorted((ROOT / top).rglob("*.py"))
        if p != COMMISSION_HOME
        for hit in constants(p, COMMISSION_NAMES)
    }
    assert where - OTHER_FOLDERS == set()


def test_a_backup_carries_the_feature_plan(tmp_path: Path) -> None:
    """The part type's feature plan goes with a backup and comes back with a restore: without
    it the restored cell would measure no body."""
    from app.line.statedir import StateDir

    state = StateDir(tmp_path)
    state.features.write_text('format = "rvis-features/1"\n')
    assert state.features in state.carried()
