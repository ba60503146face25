"""The project's packages under `rvis`'s own namespace: `rvis._impl.app.api`, never `app.api`.

rvis is laid out in the top-level packages app, calib, vision, drivers and fakes, and installs
them as such. Their names are generic: a program with a package of its own called `app` (or
`calib`, ...) shadows them, and a module named `app` in `sys.modules` is the host's business.
So `rvis` imports the modules its API needs from the same installed files under a private
prefix, `rvis._impl.<name>`: a meta path finder maps `rvis._impl.app.api` to `<root>/app/api.py`
and loads it with every absolute import of those five packages rewritten to the prefix (on the
syntax tree, as pytest rewrites its test modules' asserts), so `from calib.model import X` in
that file reads `from rvis._impl.calib.model import X`. Nothing is looked up by the generic
names, and nothing is put into `sys.modules` under them. Relative imports need no rewriting.

The copies are separate modules from the top-level ones (a process that imports both has two
`SystemModel` classes): use one or the other. The rewritten code is not cached as bytecode, so
the first `import rvis` parses and compiles the API's 19 modules (about 0.2 s, besides
numpy and scipy).
"""

from __future__ import annotations

import ast
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

PREFIX = "rvis._impl"
PACKAGES = ("app", "calib", "vision", "drivers", "fakes")
#: The folder holding the project's packages: the repository, or site-packages when installed.
ROOT = Path(__file__).resolve().parent.parent


def private_name(name: str) -> str:
    """`app.api` -> `rvis._impl.app.api` (names of other packages unchanged)."""
    return f"{PREFIX}.{name}" if name.partition(".")[0] in PACKAGES else name


class _Rewrite(ast.NodeTransformer):
    """Absolute imports of the project's packages -> the private prefix."""

    def visit_ImportFrom(self, node: ast.ImportFrom) -> ast.ImportFrom:
        if node.level == 0 and node.module:
            node.module = private_name(node.module)
        return node

    def visit_Import(self, node: ast.Import) -> list[ast.stmt]:
        out: list[ast.stmt] = []
        for alias in node.names:
            name = private_name(alias.name)
            if name == alias.name:
                out.append(ast.Import(names=[alias]))
            elif alias.asname:
                out.append(ast.Import(names=[ast.alias(name, alias.asname)]))
            else:  # `import app.x` binds `app`: load the private one, bind its top package
                top = alias.name.partition(".")[0]
                out.append(ast.Import(names=[ast.alias(name, "_rvis_private_import")]))
                out.append(ast.ImportFrom(module=PREFIX, names=[ast.alias(top)], level=0))
        return [ast.copy_location(stmt, node) for stmt in out]


class _RewritingLoader(importlib.abc.Loader):
    """Executes a project source file with its imports rewritten (_Rewrite)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return None  # the default module

    def exec_module(self, module: ModuleType) -> None:
        tree = ast.parse(self.path.read_bytes(), filename=str(self.path))
        tree = ast.fix_missing_locations(_Rewrite().visit(tree))
        exec(compile(tree, str(self.path), "exec", dont_inherit=True), module.__dict__)


class _PrefixLoader(importlib.abc.Loader):
    """`rvis._impl` itself: an empty package whose children _Finder finds."""

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return None

    def exec_module(self, module: ModuleType) -> None:
        module.__doc__ = "The project's packages, loaded under rvis's namespace (rvis._isolated)."


class _Finder(importlib.abc.MetaPathFinder):
    """Finds `rvis._impl` and `rvis._impl.<package>[.<module>...]` in ROOT."""

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None = None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname == PREFIX:
            spec = importlib.machinery.ModuleSpec(fullname, _PrefixLoader(), is_package=True)
            spec.submodule_search_locations = []
            return spec
        if not fullname.startswith(PREFIX + "."):
            return None
        parts = fullname[len(PREFIX) + 1 :].split(".")
        if parts[0] not in PACKAGES:
            return None
        base = ROOT.joinpath(*parts)
        package = base / "__init__.py"
        origin = package if package.is_file() else base.with_suffix(".py")
        if not origin.is_file():
            return None
        return importlib.util.spec_from_file_location(
            fullname,
            origin,
            loader=_RewritingLoader(origin),
            submodule_search_locations=[str(base)] if origin == package else None,
        )


def install() -> None:
    """Put the finder first on `sys.meta_path` (once): a package's children are otherwise
    found by the path finder in the package's `__path__`, which is the real folder."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def load(name: str) -> ModuleType:
    """The project module `name` (e.g. "app.api") under the private prefix."""
    if not (ROOT / name.partition(".")[0] / "__init__.py").is_file():
        raise ImportError(f"rvis: package {name.partition('.')[0]!r} not found in {ROOT}")
    install()
    return importlib.import_module(private_name(name))
