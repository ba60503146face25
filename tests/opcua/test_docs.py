"""docs/opcua.md's client example runs against the simulated line and prints what it says."""

from __future__ import annotations

import re
import subprocess
import sys

from tests.opcua.conftest import MACHINE, ROOT, Servers

DOC = ROOT / "docs" / "opcua.md"


def test_the_ten_line_client_example_runs(servers: Servers) -> None:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## A client in ten lines", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S)
    assert code is not None
    source = code.group(1)
    assert "opc.tcp://127.0.0.1:4840/rvis" in source and '"rvis-cell"' not in source
    source = source.replace("opc.tcp://127.0.0.1:4840/rvis", servers.read_only)
    source = source.replace(":rvis-cell", f":{MACHINE}")
    out = subprocess.run(
        [sys.executable, "-c", source], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert out.returncode == 0, out.stderr
    lines = dict(line.split(" ", 1) for line in out.stdout.splitlines())
    assert set(lines) == {"ServiceState", "CalibrationVersion", "CalibrationRmsMm", "ActiveAlarms"}
    assert lines["ServiceState"].split()[-1] == "Good"
    assert lines["CalibrationRmsMm"].split()[-1] in ("Good", "BadNoValue")
