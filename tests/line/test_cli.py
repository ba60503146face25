"""`rvis status`, `rvis ctl` and `rvis run` on the command line, and SIGTERM of a served
service (it stops after its window, the robot home, the database closed, the socket gone)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from app.commands.cli import main
from app.line.control import ControlServer
from app.line.launch import serve
from tests.line.helpers import Line, make_line


def _cli(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return code, out.out, out.err


@pytest.fixture()
def served(tmp_path: Path) -> Iterator[Line]:
    ln = make_line(tmp_path)
    with ControlServer(ln.service, tmp_path / "rvis.sock"):
        ln.start().wait(lambda e: e["event"] == "state" and e["to"] == "idle")
        try:
            yield ln
        finally:
            ln.close()


def test_status_and_ctl_talk_to_the_running_service(
    served: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = _cli(capsys, ["status", "--state-dir", str(tmp_path), "--json"])
    assert code == 0 and json.loads(out)["state"] in ("idle", "measuring")
    code, out, _ = _cli(capsys, ["ctl", "--state-dir", str(tmp_path), "pause"])
    assert (code, out.strip()) == (0, "paused")
    code, out, _ = _cli(capsys, ["status", "--state-dir", str(tmp_path)])
    assert out.splitlines()[0] == "state               paused: paused by the operator"
    code, _, err = _cli(capsys, ["ctl", "--state-dir", str(tmp_path), "ack", "42"])
    assert code == 1 and err.strip() == "rvis ctl: error: no unacknowledged alarm 42"
    with pytest.raises(SystemExit) as exit_info:
        main(["ctl", "--state-dir", str(tmp_path), "rollback", "x"])
    assert exit_info.value.code == 2 and "invalid int value" in capsys.readouterr().err
    actions = served.service.store.actions()
    assert [(a["cmd"], a["uid"]) for a in actions] == [("pause", os.getuid()), ("ack", os.getuid())]


def test_status_without_a_running_service_reads_the_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ln = make_line(tmp_path)
    ln.start().windows(2)
    ln.close()
    code, out, _ = _cli(capsys, ["status", "--state-dir", str(tmp_path), "--json"])
    status = json.loads(out)
    assert code == 0 and status["state"] == "not running"
    assert status["measurements"] == {"ok": 2, "rejected": 0} and status["params_version"] == 1
    code, _, err = _cli(capsys, ["ctl", "--state-dir", str(tmp_path), "resume"])
    assert code == 1 and "no service is running" in err
    code, _, err = _cli(capsys, ["status", "--state-dir", str(tmp_path / "nothing")])
    assert code == 2 and "no rvis.db" in err


def test_run_without_a_plan_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = _cli(capsys, ["run", "--state-dir", str(tmp_path)])
    assert code == 2
    # an empty state directory is one to commission (issue 40: it was told to run `rvis plan`)
    assert err.strip().startswith(f"rvis run: error: {tmp_path / 'plan.json'}: no plan file")
    assert "rvis commission --state-dir" in err and len(err.strip().splitlines()) == 1


def test_a_group_that_does_not_exist_is_named_in_the_cell_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 40: a wrong `[service] engineers_group` had no file and line."""
    cell = tmp_path / "cell.toml"
    cell.write_text('[simline]\nwarmup_k = 0.0\n\n[service]\nengineers_group = "no-such-grp"\n')
    argv = ["run", "--sim", "--geometric", "--windows", "1", "--cell", str(cell)]
    code, _, err = _cli(capsys, [*argv, "--state-dir", str(tmp_path / "state")])
    assert code == 2
    assert err.strip() == (
        f"rvis run: error: {cell}:5: [service] engineers_group: no such group 'no-such-grp'"
    )


def test_sigterm_finishes_the_window_brings_the_robot_home_and_closes(tmp_path: Path) -> None:
    ln = make_line(tmp_path)
    events = ln.service.bus.subscribe()

    def terminate_during_a_window() -> None:
        while events.get(timeout=10)["event"] != "measurement":
            pass
        os.kill(os.getpid(), signal.SIGTERM)  # the robot is out: the window must finish

    killer = threading.Thread(target=terminate_during_a_window)
    killer.start()
    try:
        serve(ln.service)  # returns on SIGTERM
    finally:
        killer.join()
        ln.close()
    assert np.allclose(ln.cell.joints_deg(), ln.service.measurer.home_deg)
    assert ln.plc.received.done and not ln.plc.received.busy
    assert not (tmp_path / "rvis.sock").exists()
    with pytest.raises(sqlite3.ProgrammingError):
        ln.service.store.counts()  # closed
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_run_on_fake_urls_is_refused_pointing_to_the_simulated_line_s_devices(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = tmp_path / "plan.json"
    plan.write_text("{}", encoding="utf-8")
    code, _, err = _cli(capsys, ["run", "--state-dir", str(tmp_path), "--plan", str(plan)])
    assert code == 2
    assert err.startswith("rvis run: error: <embedded default>: field 'devices.robot': ")
    assert "fake:// (robot, camera, galvo, tracker, plc)" in err
    assert "`rvis devices sim`" in err and len(err.strip().splitlines()) == 1
