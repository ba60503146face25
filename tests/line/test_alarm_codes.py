"""The one list of alarm codes (app.line.states.ALARM_CODES) holds every code the service can
raise: read from the source, every `alarm(...)`, `raise_alarm(...)` and `_enter_fault(...)`
with a literal code, and every literal `(code, message, priority)` queued for the start."""

from __future__ import annotations

import ast
from pathlib import Path

from app.line.states import ALARM_CODES, FAULT_CODES

APP = Path(__file__).resolve().parents[2] / "app"
RAISERS = {"alarm": 0, "_enter_fault": 0, "raise_alarm": 1}  # name -> index of the code


def raised_codes() -> dict[str, list[str]]:
    """code -> where it is raised (file:line), for every literal code in app/."""
    found: dict[str, list[str]] = {}
    for path in sorted(APP.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
                continue
            name = node.func.attr
            arg: ast.expr | None = None
            if name in RAISERS and len(node.args) > RAISERS[name]:
                arg = node.args[RAISERS[name]]
            elif name == "append" and node.args and isinstance(node.args[0], ast.Tuple):
                target = ast.unparse(node.func.value)
                if target.endswith("_start_alarms") and node.args[0].elts:
                    arg = node.args[0].elts[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                where = f"{path.relative_to(APP.parent)}:{node.lineno}"
                found.setdefault(arg.value, []).append(where)
    return found


def test_every_raised_code_is_in_the_one_list() -> None:
    found = raised_codes()
    unknown = {code: where for code, where in found.items() if code not in ALARM_CODES}
    assert not unknown, f"add these codes to app.line.states.ALARM_CODES: {unknown}"
    # the scan sees the service's raisers (a scan that finds nothing proves nothing)
    assert {"sensor", "drift_step", "plc_heartbeat", "params_rebuilt", "internal_error"} <= set(
        found
    )


def test_the_list_is_the_raised_codes_and_the_fault_codes() -> None:
    """No code listed that nothing raises (the fault codes may come through `_enter_fault`
    with a variable code); every class is a known one."""
    assert set(FAULT_CODES) <= set(ALARM_CODES)
    assert set(ALARM_CODES) == set(raised_codes()) | set(FAULT_CODES)
    assert set(ALARM_CODES.values()) == {"process", "system"}
