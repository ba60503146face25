"""The commands that only talk to the service's socket or read its state directory (`rvis status`,
`rvis ctl`, `rvis state check`, `rvis state suspects`) import only what they use: no numerics,
no devices' field-bus libraries, no UI (issue 31: `rvis status` took 0.74 s and 147 MiB to say
that no service runs, numpy and scipy loaded through the service's modules and the cell file's).

Each command runs as its own process, as an operator's script runs it, under `-X importtime`,
whose report names every module the process imported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from app.line.control import ControlServer
from app.line.statedir import StateDir
from app.line.store import Store
from app.state_defaults import DEFAULT_ROOT

ROOT = Path(__file__).resolve().parents[2]
#: what these commands never need: numerics, vision, UI, OPC UA, Modbus (top-level packages)
HEAVY = ("numpy", "scipy", "calib", "vision", "cv2", "textual", "asyncua", "pymodbus")


@dataclass
class Run:
    code: int
    out: str
    err: list[str]  # stderr without the import report
    modules: set[str]

    def heavy(self) -> set[str]:
        """The heavy packages' modules imported, and the service's (app.line.service)."""
        return {m for m in self.modules if m.split(".")[0] in HEAVY or m == "app.line.service"}


def rvis(*argv: str, cwd: Path = ROOT) -> Run:
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "app", *argv],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=60,
    )
    report = [line for line in done.stderr.splitlines() if line.startswith("import time:")]
    modules = {line.rsplit("|", 1)[1].strip() for line in report[1:]}  # [0] is the header
    err = [line for line in done.stderr.splitlines() if not line.startswith("import time:")]
    return Run(done.returncode, done.stdout, err, modules)


@pytest.fixture()
def state(tmp_path: Path) -> StateDir:
    """A state directory as a stopped service leaves it: a database with a suspect interval
    in which the PLC clamped two bodies, and parameters version 3 in force."""
    state = StateDir(tmp_path / DEFAULT_ROOT)
    state.root.mkdir(mode=0o750)
    store = Store(state.db)
    store.open_suspect({"t_start": 1.8e9, "onset_id": 12, "size_mm": 0.31, "text": "sensor"})
    for t, body in ((1.8e9 - 60.0, 100006), (1.8e9 + 60.0, 100007), (1.8e9 + 120.0, 100008)):
        store.add_window(t, body)
    store.close()
    state.history.mkdir(parents=True)
    for path in (state.history / "0003.json", state.current):
        path.write_text(json.dumps({"history_version": 3}))
    for path in (state.root / "rvis.db", state.current, state.history / "0003.json"):
        path.chmod(0o640)
    return state


class _Service:
    """Answers every command at once, as the service does when it accepts it."""

    bus: Any = None

    def __init__(self) -> None:
        self.asked: list[tuple[str, dict[str, Any]]] = []
        self.status: dict[str, Any] = {"state": "idle"}

    def request(
        self,
        cmd: str,
        args: dict[str, Any] | None = None,
        uid: int | None = None,
        groups: tuple[int, ...] | None = None,
    ) -> Any:
        self.asked.append((cmd, args or {}))
        reply: Future[dict[str, Any]] = Future()
        if cmd == "status":
            reply.set_result({"ok": True, **self.status})
        else:
            reply.set_result({"ok": True, "state": "idle", "message": f"{cmd}: done"})
        return reply


@pytest.fixture()
def service(state: StateDir) -> Iterator[_Service]:
    svc = _Service()
    with ControlServer(svc, state.socket):
        yield svc


def test_status_without_a_service_reads_the_database_only(state: StateDir) -> None:
    run = rvis("status", "--json", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    status = json.loads(run.out)
    assert status["state"] == "not running" and status["params_version"] == 3
    assert [s["size_mm"] for s in status["suspect_intervals"]] == [0.31]
    assert [s["bodies"] for s in status["suspect_intervals"]] == [[100007, 100008]]
    assert "app.line.store" in run.modules  # the report is read: it names what was imported
    assert run.heavy() == set()


def test_status_without_a_service_states_the_last_accuracy_stored(state: StateDir) -> None:
    """Issue 51: once the service stopped, status said "accuracy not stated yet" and gave
    `accuracy: null`, though every window's U95 is stored: the last statement (the service's
    saved state), with the window it was stated for."""
    store = Store(state.db)
    statement = {"u95_mm": 0.052, "n": 24, "basis": "estimator", "limit_mm": 0.1, "vouched": True}
    store.save_state(1.8e9 + 125.0, {"accuracy": statement})
    store.state_window_u95(0.052)  # the last window's (1.8e9 + 120)
    store.close()
    run = rvis("status", "--json", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    assert json.loads(run.out)["accuracy"] == {
        **statement,
        "window_utc": "2027-01-15T08:02:00+00:00",
    }
    text = rvis("status", "--state-dir", str(state.root)).out
    assert (
        "accuracy            U95 0.052 mm (24 measurements, estimator), limit 0.100 mm: vouched for"
        " (the last window's, 2027-01-15T08:02:00+00:00; the service is not running)"
    ) in text.splitlines()
    assert run.heavy() == set()


def test_status_while_a_service_starts_and_on_a_file(state: StateDir, tmp_path: Path) -> None:
    """Issue 40: while a service holds the directory's lock and its socket is not up yet (the
    simulated line computes its world for ~20 s) status said "not running"; on a file it
    exited 1."""
    from app.line.statedir import ServiceLock

    with ServiceLock(state):
        run = rvis("status", "--state-dir", str(state.root))
        assert run.code == 0, run.err
        assert run.out.startswith(f"state               starting (pid {os.getpid()})")
        doc = json.loads(rvis("status", "--json", "--state-dir", str(state.root)).out)
        assert doc == {"state": "starting", "pid": os.getpid(), "socket": False}
    assert "not running" in rvis("status", "--state-dir", str(state.root)).out
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    run = rvis("status", "--state-dir", str(a_file))
    assert run.code == 2 and run.err == [
        f"rvis status: error: {a_file}: not a state directory (a file)"
    ]


def test_status_in_the_default_state_directory_loads_no_cell_file(state: StateDir) -> None:
    run = rvis("status", cwd=state.root.parent)  # ./rvis-state, the default
    assert run.code == 0, run.err
    assert "state               not running" in run.out
    assert "app.config" not in run.modules and run.heavy() == set()


def test_status_and_ctl_through_the_socket(state: StateDir, service: _Service) -> None:
    run = rvis("status", "--json", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    assert json.loads(run.out)["state"] == "idle" and run.heavy() == set()
    run = rvis("ctl", "pause", "--state-dir", str(state.root))
    assert (run.code, run.out.strip()) == (0, "pause: done") and run.heavy() == set()
    run = rvis("ctl", "--state-dir", str(state.root), "shelve", "7", "dusty", "--minutes", "5")
    assert run.code == 0 and run.heavy() == set()
    assert service.asked[1:] == [
        ("pause", {}),
        ("shelve", {"alarm": 7, "reason": "dusty", "minutes": 5.0}),
    ]


def test_plain_status_says_the_step_temperature_devices_and_spheres(
    state: StateDir, service: _Service
) -> None:
    """Issue 30 item 10: what only `--json` said, in words too."""
    service.status = {
        "state": "idle",
        "step": "waiting for a window",
        "params_version": 4,
        "cell_temp_c": 23.46,
        "devices": {
            "robot": {"state": "ok", "last_error": None},
            "plc": {
                "state": "no heartbeat",
                "last_error": "PlcTimeout: no answer",
                "last_error_utc": "2026-11-25T06:00:00Z",
            },
        },
        "spheres": {
            "P1": {"n": 3, "residual_mm": 0.0412, "posterior_rms_mm": 0.0213},
            "P2": {"n": 0, "residual_mm": None, "posterior_rms_mm": None},
        },
        "measurements": {"ok": 12, "rejected": 1},
        "alarms": [],
    }
    run = rvis("status", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    lines = run.out.splitlines()
    assert "state               idle: waiting for a window" in lines
    assert "cell temperature    23.5 degC" in lines
    assert "devices             robot ok, plc no heartbeat" in lines
    assert "  plc: last error PlcTimeout: no answer (2026-11-25T06:00:00Z)" in lines
    assert "spheres             residual of the newest measurement, mm: P1 0.041, P2 -" in lines
    assert "                    RMS left by the estimator, mm: P1 0.021, P2 -" in lines
    service.status = {**service.status, "cell_temp_c": None}
    assert "cell temperature    unknown" in rvis("status", "--state-dir", str(state.root)).out
    assert run.heavy() == set()
    # the jump in hand, in words
    jump = {"text": "step of the cell since measurement 31 (p < 1e-12)", "what": "sensor mount"}
    service.status = {**service.status, "jump": jump | {"corrected_version": 4}}
    lines = rvis("status", "--state-dir", str(state.root)).out.splitlines()
    assert (
        "step                step of the cell since measurement 31 (p < 1e-12): sensor mount;"
        " corrected by version 4, confirming" in lines
    )


def test_ctl_without_a_service(state: StateDir) -> None:
    run = rvis("ctl", "resume", "--state-dir", str(state.root))
    (line,) = run.err
    assert run.code == 1 and line == f"rvis ctl: error: no service is running at {state.socket}"
    assert run.heavy() == set()


def test_state_check_and_suspects_read_the_database_only(state: StateDir) -> None:
    run = rvis("state", "check", "--json", "--state-dir", str(state.root))
    findings = json.loads(run.out)
    assert run.code == 0, findings["problems"]
    assert findings["parameters"]["current_version"] == 3 and findings["service_pid"] is None
    assert run.heavy() == set()
    run = rvis("state", "check", "--state-dir", str(state.root))  # words, not a Python dict
    assert run.code == 0 and "{" not in run.out
    assert "measurements 0 ok, 0 rejected" in run.out and "commissioned     no" in run.out
    run = rvis("state", "suspects", "--json", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    (interval,) = json.loads(run.out)
    assert (interval["state"], interval["size_mm"]) == ("open", 0.31)
    assert interval["bodies"] == [100007, 100008]
    assert run.heavy() == set()
    run = rvis("state", "suspects", "--state-dir", str(state.root))
    assert run.code == 0 and "bodies (2: 100007 .. 100008): 100007, 100008" in run.out
    assert run.heavy() == set()


def test_state_body_says_how_sure_the_measurement_of_a_body_is(state: StateDir) -> None:
    """Issue 51: no command answered "how sure is the measurement of body 100008?": the
    window it was clamped in, the parameters version in force then, the U95 the cell stated
    for its bodies, the suspect intervals it falls in (a body never measured here: one line,
    exit 2)."""
    store = Store(state.db)
    store.add_applied(1.8e9 - 3600.0, 3, None, "auto", None)
    store.state_window_u95(0.052)  # the last window's: body 100008
    store.close()
    run = rvis("state", "body", "100008", "--json", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    doc = json.loads(run.out)
    assert doc["body"] == 100008
    assert doc["windows"] == [
        {"t_utc": "2027-01-15T08:02:00+00:00", "params_version": 3, "u95_mm": 0.052}
    ]
    assert [(s["id"], s["size_mm"]) for s in doc["suspect_intervals"]] == [(1, 0.31)]
    assert doc["suspect"] is True and doc["measured"] is None
    assert run.heavy() == set()
    text = rvis("state", "body", "100008", "--state-dir", str(state.root)).out.splitlines()
    assert text[0] == (
        "body 100008: clamped in the window of 2027-01-15T08:02:00+00:00, parameters version 3;"
        " the cell stated U95 0.052 mm for a point measured then"
    )
    assert text[1].startswith("SUSPECT: in suspect interval #1 (2027-01-15T08:00:00+00:00 .. open,")
    clean = rvis("state", "body", "100006", "--state-dir", str(state.root)).out.splitlines()
    assert clean[-1] == "not in a suspect interval"
    run = rvis("state", "body", "999", "--state-dir", str(state.root))
    assert run.code == 2 and run.err == [
        "rvis state: error: field 'BODY': no body '999' clamped or measured here"
    ]


#: the `maintenance` alarm's text the service raised for axis 3's zero moved (seed 6, the
#: simulated line's `maintenance_kind = "axis"`; app.line.beyond_knock.change_need's text, as
#: an older rvis stored it: no fields beside it)
AXIS3_TEXT = (
    "a change of 9.91 mm at the measured spheres, beyond a knock's 1.5 mm: J3 zero moved 0.4935"
    " deg (9.91 mm at the measured spheres), 3 measurements; next sphere fixture / part frame"
    " by BIC 12818; likely the motor or encoder of axis 3 replaced (its zero moved) (J3 zero"
    " 0.4935 deg (9.91 mm at the measured spheres)); bodies are not measured with this cell:"
    " run `rvis maintain axis 3`"
)


def _maintenance(state: StateDir, *, alarm: bool, running: bool) -> None:
    """A done fixture procedure (version 1 -> 2); the `maintenance` alarm for axis 3; axis 3's
    procedure stopped after two steps, its third started (journal.json as app/commission's)."""
    store = Store(state.db)
    done = store.start_maintenance(
        {
            "t_start": 1.7e9,
            "event": "fixture",
            "who": "anna",
            "folder": "maintenance/0001-fixture",
            "version_before": 1,
            "before": {"version": 1, "validation_rmse_mm": 0.061},
        }
    )
    store.finish_maintenance(done, 1.7e9 + 1800.0, 2, {"version": 2, "validation_rmse_mm": 0.064})
    if alarm:
        store.raise_alarm(1.8e9 + 200.0, "maintenance", AXIS3_TEXT, "urgent")
    if running:
        store.start_maintenance(
            {
                "t_start": 1.8e9 + 300.0,
                "event": "axis",
                "axis": 3,
                "who": "ben",
                "folder": "maintenance/0002-axis3",
                "version_before": 3,
            }
        )
        folder = state.root / "maintenance" / "0002-axis3"
        folder.mkdir(parents=True)
        step = {"started_utc": "2027-01-15T08:05:00+00:00", "seconds": 1.0, "checks": []}
        steps = [
            {**step, "name": "devices", "status": "passed", "results": {}, "files": []},
            {**step, "name": "prepare", "status": "passed", "results": {}, "files": []},
            {**step, "name": "zero", "status": "started", "results": {}, "files": []},
        ]
        doc = {"format": "rvis-maintain/1", "setup": {"event": "axis"}, "steps": steps}
        (folder / "journal.json").write_text(json.dumps(doc))
    store.close()


def test_status_says_the_cell_needs_maintenance_and_which(state: StateDir) -> None:
    """Issue 41: a cell held for maintenance says so (what moved, the procedure that fits), not
    only a FAULT among the alarms; the last procedure done, with its versions."""
    _maintenance(state, alarm=True, running=False)
    run = rvis("status", "--state-dir", str(state.root))
    assert run.code == 0, run.err
    lines = run.out.splitlines()
    assert (
        "maintenance needed  likely the motor or encoder of axis 3 replaced (its zero moved) (J3"
        " zero 0.4935 deg (9.91 mm at the measured spheres)); run `rvis maintain axis 3`" in lines
    )
    assert (
        "last maintenance    fixture done 2023-11-14T22:43:20+00:00, by anna, version 1 -> 2"
        " (workspace validation RMS 0.061 -> 0.064 mm, worse by 0.003 mm, +5 %)" in lines
    )
    assert not any(line.startswith("in maintenance") for line in lines)
    assert run.heavy() == set()
    m = json.loads(rvis("status", "--json", "--state-dir", str(state.root)).out)["maintenance"]
    assert m["needed"]["procedures"] == ["rvis maintain axis 3"]
    assert m["needed"]["text"] == AXIS3_TEXT and m["needed"]["alarm_id"] == 1
    assert m["running"] is None
    assert (m["last_done"]["event"], m["last_done"]["version_after"]) == ("fixture", 2)
    assert [r["status"] for r in m["records"]] == ["done"]


def test_status_while_a_procedure_runs_says_its_step(state: StateDir) -> None:
    """`rvis maintain` holds the state directory: status says "maintenance" (not "starting"),
    who runs which procedure since when, and how far its journal got; stopped half-way (the
    lock free), the same from the database."""
    from app.line.statedir import ServiceLock

    _maintenance(state, alarm=True, running=True)
    progress = (
        "in maintenance      axis (axis 3) since 2027-01-15T08:05:00+00:00, by ben, 2 steps"
        " passed, next: zero (started), folder maintenance/0002-axis3"
    )
    with ServiceLock(state):
        run = rvis("status", "--state-dir", str(state.root))
        assert run.code == 0, run.err
        lines = run.out.splitlines()
        assert lines[0].startswith(
            f"state               maintenance: `rvis maintain` (pid {os.getpid()})"
        )
        assert progress in lines and run.heavy() == set()
        doc = json.loads(rvis("status", "--json", "--state-dir", str(state.root)).out)
        assert (doc["state"], doc["pid"]) == ("maintenance", os.getpid())
        running = doc["maintenance"]["running"]
        assert (running["event"], running["axis"], running["who"]) == ("axis", 3, "ben")
        assert running["progress"] == {
            "steps_passed": 2,
            "passed": ["devices", "prepare"],
            "next_step": "zero",
            "next_status": "started",
        }
    lines = rvis("status", "--state-dir", str(state.root)).out.splitlines()
    assert lines[0] == "state               not running" and progress in lines
