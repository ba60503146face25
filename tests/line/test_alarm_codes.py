"""The one list of alarm codes (app.line.states.AlarmCode, ALARM_CODES its mapping to condition
classes) holds every code the service can raise, and the service names them by its members,
never by a bare string: read from the source, every `alarm(...)`, `raise_alarm(...)` and
`enter_fault(...)`, every `clear_alarms(...)` and `active_alarms(...)`, every `(code, message,
priority)` queued for the start and every `alarm_cleared` event's code."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from app.line.states import ALARM_CODES, FAULT_CODES, AlarmCode

APP = Path(__file__).resolve().parents[2] / "app"
#: the calls that take an alarm code -> the index of the code among their positional arguments
#: (None: any of them, the others are never strings: clear_alarms(t, code) of the store or
#: (code, t) of the service); `code=` by keyword too
TAKERS: dict[str, int | None] = {
    "alarm": 0,
    "enter_fault": 0,
    "raise_alarm": 1,
    "clear_alarms": None,
    "active_alarms": None,
}


def _code_args(node: ast.Call) -> list[ast.expr]:
    """The arguments of `node` that are alarm codes (none when it takes no code)."""
    if not isinstance(node.func, ast.Attribute):
        return []
    name, args = node.func.attr, node.args
    if name in TAKERS:
        k = TAKERS[name]
        found = list(args) if k is None else args[k : k + 1]
        return found + [kw.value for kw in node.keywords if kw.arg == "code"]
    queue = ast.unparse(node.func.value)
    if name == "append" and args and isinstance(first := args[0], ast.Tuple) and first.elts:
        return [first.elts[0]] if queue.endswith("start_alarms") else []
    if name == "emit" and len(args) > 1 and isinstance(args[1], ast.Dict):
        event = args[0]
        if isinstance(event, ast.Constant) and str(event.value).startswith("alarm"):
            return [v for k, v in zip(args[1].keys, args[1].values, strict=True)
                    if isinstance(k, ast.Constant) and k.value == "code"]  # fmt: skip
    return []


def scan(source: str, where: str) -> tuple[dict[str, list[str]], list[str]]:
    """(code -> where it is named as an AlarmCode member, the bare string codes with where)."""
    named: dict[str, list[str]] = {}
    bare: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        for arg in _code_args(node):
            at = f"{where}:{arg.lineno}"
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                bare.append(f"{at} {arg.value!r}")
            elif (
                isinstance(arg, ast.Attribute)
                and isinstance(arg.value, ast.Name)
                and arg.value.id == "AlarmCode"
            ):
                named.setdefault(AlarmCode[arg.attr].value, []).append(at)
    return named, bare


def app_codes() -> tuple[dict[str, list[str]], list[str]]:
    """scan() over every module of app/."""
    named: dict[str, list[str]] = {}
    bare: list[str] = []
    for path in sorted(APP.rglob("*.py")):
        n, b = scan(path.read_text(encoding="utf-8"), str(path.relative_to(APP.parent)))
        bare += b
        for code, where in n.items():
            named.setdefault(code, []).extend(where)
    return named, bare


def test_no_alarm_code_is_a_bare_string() -> None:
    named, bare = app_codes()
    assert not bare, f"name these alarm codes by app.line.states.AlarmCode: {bare}"
    # the scan sees the service's raisers, clears and look-ups (a scan that finds nothing
    # proves nothing): among them every kind of call
    assert {"sensor", "drift_step", "plc_heartbeat", "params_rebuilt", "internal_error"} <= set(
        named
    )
    calls = {w for where in named.values() for w in where}
    assert len(calls) >= 30, sorted(calls)


@pytest.mark.parametrize(
    "source",
    [
        'self.alarm("sensor", "text", "low")',
        'svc.store.clear_alarms(t, "sensor")',
        'self.clear_alarms("sensor", t)',
        'self.store.active_alarms(code="sensor")',
        'self.store.raise_alarm(t, "sensor", "text", "low")',
        'self.faults.enter_fault("sensor", "text")',
        'start_alarms.append(("sensor", "text", "high"))',
        'self.bus.emit("alarm_cleared", {"code": "sensor"})',
    ],
)
def test_the_scan_finds_a_bare_code_in_each_kind_of_call(source: str) -> None:
    named, bare = scan(source, "x.py")
    assert bare == ["x.py:1 'sensor'"] and named == {}
    named, bare = scan(source.replace('"sensor"', "AlarmCode.SENSOR", 1), "x.py")
    assert bare == [] and named == {"sensor": ["x.py:1"]}


def test_the_list_is_the_named_codes_and_the_fault_codes() -> None:
    """No code listed that nothing raises (the fault codes may come through `enter_fault`
    with a variable code); every class is a known one."""
    assert set(FAULT_CODES) <= set(ALARM_CODES)
    assert set(ALARM_CODES) == set(app_codes()[0]) | set(FAULT_CODES)
    assert set(ALARM_CODES.values()) == {"process", "system"}
    assert AlarmCode.SENSOR == "sensor" and ALARM_CODES["sensor"] == "process"
