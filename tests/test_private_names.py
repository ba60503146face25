"""No module of app/ imports another module's private name (issue 51 item 4): what one module
takes from another is public, named without a leading underscore and documented; a helper two
commands share lives in a module both import (app/commands/guided.py), not in one of them."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module_of(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_from(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute name of the module `node` imports from (a relative import resolved)."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def private_imports(path: Path, root: Path = ROOT, top: str = "app") -> list[str]:
    """`path:line imports NAME from MODULE` for each private name (a leading underscore, not a
    dunder) that the module at `path` (below `root`) imports from another module of the
    package `top`."""
    module = _module_of(path, root)
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom):
            continue
        source = _imported_from(node, module, path.name == "__init__.py")
        if source != top and not source.startswith(top + "."):
            continue
        if source == module:
            continue
        for alias in node.names:
            name = alias.name
            if name.startswith("_") and not (name.startswith("__") and name.endswith("__")):
                found.append(f"{path.relative_to(root)}:{node.lineno} imports {name} from {source}")
    return found


def test_no_private_name_is_imported_across_modules_of_app() -> None:
    bad = [line for path in sorted((ROOT / "app").rglob("*.py")) for line in private_imports(path)]
    assert not bad, "\n".join(bad)


def test_the_check_sees_a_private_import(tmp_path: Path) -> None:
    """The scan finds absolute and relative imports of another module's private name, and
    passes over public names, dunders, other packages and a module importing itself."""
    root = tmp_path
    (root / "app" / "commands").mkdir(parents=True)
    (root / "app" / "__init__.py").write_text("")
    (root / "app" / "commands" / "__init__.py").write_text("from .x import _y\n")
    mine = root / "app" / "commands" / "m.py"
    mine.write_text(
        "from app.commands.commission import _finish, printer\n"
        "from .guided import _confirmation\n"
        "from ..sim import shift as _shift\n"
        "from app import __version__\n"
        "from fakes.truth import _rot\n"
        "from app.commands.m import _self\n"
    )
    init = root / "app" / "commands" / "__init__.py"
    found = private_imports(mine, root) + private_imports(init, root)
    assert found == [
        "app/commands/m.py:1 imports _finish from app.commands.commission",
        "app/commands/m.py:2 imports _confirmation from app.commands.guided",
        "app/commands/__init__.py:1 imports _y from app.commands.x",
    ]
