"""The dependency rule of DESIGN.md section 3, checked on the source (AST imports)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("app", "calib", "vision", "drivers", "fakes", "rvis")
FORBIDDEN = {
    # rvis is the API's public face (rvis/__init__.py) on top of everything: nothing imports it
    "app": {"rvis"},
    "calib": {"app", "drivers", "fakes", "rvis"},
    "vision": {"app", "drivers", "fakes", "rvis"},
    # a driver moves joints and grabs frames; fake:// is registered by whoever wires the fakes
    "drivers": {"app", "calib", "vision", "fakes", "rvis"},
    # the simulated world has its own kinematics and renderer, never the estimators under test
    "fakes": {"app", "calib", "vision", "rvis"},
}


def named_layers(path: Path) -> set[tuple[str, int]]:
    """Modules of the layers named in string constants ("fakes.devices:FakeRobot"): an import
    by name (importlib) that the import statements do not show."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: set[tuple[str, int]] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            head = node.value.split(":")[0]
            top = head.split(".")[0]
            if (
                top in LAYERS and top != "rvis" and "." in head and " " not in head
            ):  # rvis.*: loggers
                found.add((top, node.lineno))
    return found


def imported_layers(path: Path) -> set[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: set[tuple[str, int]] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            if top in LAYERS:
                found.add((top, node.lineno))
    return found


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_only_what_it_may(layer: str) -> None:
    bad = [
        f"{path.relative_to(ROOT)}:{line} imports {top}"
        for path in sorted((ROOT / layer).rglob("*.py"))
        for top, line in sorted(imported_layers(path) | named_layers(path))
        if top in FORBIDDEN[layer]
    ]
    assert not bad, "\n".join(bad)


def test_rule_checker_sees_a_violation(tmp_path: Path) -> None:
    bad = tmp_path / "m.py"
    bad.write_text("import numpy\nfrom app.commands.cli import main\nimport drivers.base as b\n")
    assert imported_layers(bad) == {("app", 2), ("drivers", 3)}


def _module_of(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the modules of the tree it imports (at the top, in functions and under
    TYPE_CHECKING alike: an import that runs back is a circle wherever it stands)."""
    files = {_module_of(p): p for layer in LAYERS for p in (ROOT / layer).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        targets: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets.add(node.module)
                targets |= {f"{node.module}.{a.name}" for a in node.names}
        graph[module] = {t for t in targets if t in files and t != module}
    return graph


def test_no_import_circles() -> None:
    """No module reaches itself through imports (app.line's collaborators see the service as
    app.line.host.LineHost, not by importing app.line.service; a package's __init__ that
    re-exports its modules is not counted as importing its parent back)."""
    graph = _import_graph()
    circles: list[list[str]] = []
    state: dict[str, int] = {}  # 1: on the path, 2: done
    path: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        path.append(m)
        for n in sorted(graph[m]):
            if n.startswith(m + "."):  # a package importing its own modules
                continue
            if state.get(n) == 1:
                circles.append([*path[path.index(n) :], n])
            elif n not in state:
                visit(n)
        path.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert circles == [], "\n".join(" -> ".join(c) for c in circles)
