"""`import rvis`: the API under a name that cannot collide. A program in a folder of its own,
with its own `app` and `calib` packages first on sys.path, imports the installed rvis API and
its own packages side by side (in either order) and gets the numbers of `app.api`; rvis puts no
module called app, calib, vision, drivers or fakes into sys.modules."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rvis
from app.api import Calibration
from rvis._isolated import _Rewrite
from tests.inuse.conftest import Calibrated

PROGRAM = """
import json, sys

HOST_FIRST = sys.argv[2] == "host-first"
if HOST_FIRST:
    import app, calib
    from app.api import greet
import rvis
from rvis import Calibration, CompensationSettings, InputError, command_xyzwpr
if not HOST_FIRST:
    import app, calib
    from app.api import greet

cal = Calibration.load(sys.argv[1])
q = [[10.0, 20.0, -5.0, 30.0, -60.0, 15.0], [-20.0, 35.0, 10.0, -40.0, 70.0, 0.0]]
p = [[1.0, -2.0, 130.0], [0.0, 3.0, 128.0]]
comp = cal.compensate_joints(q, CompensationSettings(max_joint_change_deg=10.0))
try:
    Calibration.load("missing.json")
    refused = ""
except InputError as exc:
    refused = str(exc)
try:
    cal.to_part([[float("nan")] * 6], [[0.0, 0.0, 130.0]])
    nan_error = ""
except ValueError as exc:
    nan_error = str(exc)
generic = ("app", "calib", "vision", "drivers", "fakes")
print(json.dumps({
    "host": [greet(), calib.NAME, app.__file__],
    "loaded": sorted(
        f"{name} {getattr(m, '__file__', '')}" for name, m in sys.modules.items()
        if name.partition(".")[0] in generic
    ),
    "to_part": cal.to_part(q, p).tolist(),
    "compensated": comp.q_deg.tolist(),
    "xyzwpr": command_xyzwpr(comp).tolist(),
    "refused": refused,
    "nan_error": nan_error,
}))
"""


def host_program(folder: Path) -> Path:
    """A program with packages of its own named like rvis's: app (with an api module) and
    calib."""
    (folder / "app").mkdir(parents=True)
    (folder / "app" / "__init__.py").write_text('"""The host\'s own app."""\n')
    (folder / "app" / "api.py").write_text("def greet() -> str:\n    return 'host app'\n")
    (folder / "calib").mkdir()
    (folder / "calib" / "__init__.py").write_text("NAME = 'host calib'\n")
    main = folder / "main.py"
    main.write_text(PROGRAM)
    return main


def run_host(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """The program as its user runs it: its folder first on sys.path (the script's folder)
    and the working directory, the installed rvis on the interpreter's path."""
    return subprocess.run(
        [sys.executable, *args], cwd=folder, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("order", ["host-first", "rvis-first"])
def test_a_program_with_its_own_app_package_uses_the_rvis_api(
    calibrated: Calibrated, tmp_path: Path, order: str
) -> None:
    folder = tmp_path / "host"
    host_program(folder)
    done = run_host(folder, "main.py", str(calibrated.params), order)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["host"] == ["host app", "host calib", str(folder / "app" / "__init__.py")]
    # the only generic-named modules are the host's own
    assert out["loaded"] == sorted(
        f"{name} {folder / path}"
        for name, path in (
            ("app", "app/__init__.py"),
            ("app.api", "app/api.py"),
            ("calib", "calib/__init__.py"),
        )
    )
    cal = Calibration.load(calibrated.params)  # the same numbers as app.api in this process
    q = np.array([[10.0, 20.0, -5.0, 30.0, -60.0, 15.0], [-20.0, 35.0, 10.0, -40.0, 70.0, 0.0]])
    p = np.array([[1.0, -2.0, 130.0], [0.0, 3.0, 128.0]])
    np.testing.assert_array_equal(np.array(out["to_part"]), cal.to_part(q, p))  # bit for bit
    comp = cal.compensate_joints(q)
    assert np.abs(np.array(out["compensated"]) - comp.q_deg).max() < 1e-9
    assert out["refused"] == "missing.json: cannot read file: No such file or directory"
    assert out["nan_error"].startswith("q_deg[0, 0] = nan")


def test_without_rvis_the_host_app_shadows_the_installed_one(
    calibrated: Calibrated, tmp_path: Path
) -> None:
    """Why `rvis` exists: in the host's folder, `app.api` is the host's."""
    folder = tmp_path / "host"
    host_program(folder)
    done = run_host(folder, "-c", "from app.api import Calibration")
    assert done.returncode != 0
    assert "cannot import name 'Calibration' from 'app.api'" in done.stderr


def test_rvis_exports_the_api() -> None:
    assert sorted(rvis.__all__) == sorted(
        ["MODEL_NAME", "MODEL_VERSION", "Calibration", "Compensation", "CompensationSettings",
         "InputError", "command_xyzwpr", "load_parameters"]
    )  # fmt: skip
    # no other public name (issue 51: TYPE_CHECKING and annotations were)
    assert sorted(n for n in dir(rvis) if not n.startswith("_")) == sorted(rvis.__all__)
    assert rvis.Calibration.__module__ == "rvis._impl.app.api"
    assert rvis.MODEL_NAME == "fanuc-m710ic50-mdh30"
    assert rvis.Calibration is not Calibration  # a separate copy, by design


def test_imports_of_the_projects_packages_are_rewritten_to_the_private_prefix() -> None:
    source = (
        "import numpy\nimport calib.model\nimport calib.wpr as w\nfrom app.errors import E\n"
        "from . import x\nfrom .y import z\nimport appdirs\nfrom calibre import c\n"
    )
    tree = ast.fix_missing_locations(_Rewrite().visit(ast.parse(source)))
    assert ast.unparse(tree).splitlines() == [
        "import numpy",
        "import rvis._impl.calib.model as _rvis_private_import",
        "from rvis._impl import calib",
        "import rvis._impl.calib.wpr as w",
        "from rvis._impl.app.errors import E",
        "from . import x",
        "from .y import z",
        "import appdirs",
        "from calibre import c",
    ]
