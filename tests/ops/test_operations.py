"""Operations (issue 19): each case ends with the service running or a clear refusal, never a
silent death, never a lost stored measurement."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import sqlite3
import stat
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.ops.conftest import ROOT, RVIS, ServiceProcess, count, rvis, status

TMUX = shutil.which("tmux")
SUBSCRIBER = """
import json, socket, sys
s = socket.socket(socket.AF_UNIX)
s.connect(sys.argv[1])
s.sendall(b'{"id": 1, "cmd": "subscribe"}\\n')
f = s.makefile("rb")
for _ in range(int(sys.argv[2])):
    f.readline()
s.close()  # gone while events flow
"""


def _request(path: Path, payload: bytes) -> dict:
    with socket.socket(socket.AF_UNIX) as s:
        s.settimeout(30)
        s.connect(str(path))
        s.sendall(payload)
        line = s.makefile("rb").readline()
    out: dict = json.loads(line)
    return out


def test_clients_that_come_and_go_never_end_the_service(service: ServiceProcess) -> None:
    sock = service.state_dir / "rvis.sock"
    subs = [
        subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(sock), str(k)], cwd=ROOT)
        for k in (1, 3, 5, 8)
    ]
    for p in subs:
        assert p.wait(30) == 0
    results: list[dict] = []
    lock = threading.Lock()

    def client() -> None:
        reply = _request(sock, b'{"id": 7, "cmd": "status"}\n')
        with lock:
            results.append(reply)

    threads = [threading.Thread(target=client) for _ in range(50)]  # 50 at once
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert len(results) == 50 and all(r["ok"] and r["id"] == 7 for r in results)
    huge = _request(sock, b'{"cmd": "status", "pad": "' + b"x" * 200_000 + b'"}\n')
    assert huge == {"id": None, "ok": False, "error": "request line too long"}
    bad = _request(sock, b"\xff\xfe not json\n")
    assert bad["ok"] is False and "bad request" in bad["error"]
    service.wait_windows(2)  # still measuring
    assert service.alive and status(service.state_dir)["state"] in ("idle", "measuring")


@pytest.mark.skipif(TMUX is None, reason="tmux not installed")
def test_quitting_the_operators_terminal_leaves_the_service_running(
    service: ServiceProcess,
) -> None:
    assert TMUX is not None
    tmux = [TMUX, "-L", f"rvis-ops-{os.getpid()}", "-f", "/dev/null"]
    cmd = f"{sys.executable} -m app tui --state-dir {service.state_dir}"
    for _ in range(2):  # open and quit twice while the line measures
        subprocess.run(
            [*tmux, "new-session", "-d", "-s", "t", "-x", "100", "-y", "30", cmd],
            check=True,
            cwd=ROOT,
        )
        try:
            attached = threading.Event()
            for _ in range(300):
                out = subprocess.run([*tmux, "capture-pane", "-p", "-t", "t"], capture_output=True)
                first = out.stdout.decode(errors="replace").split("\n", 1)[0].strip()
                if first.split(" ", 1)[0] in ("idle", "measuring"):
                    attached.set()
                    break
                attached.wait(0.1)
            assert attached.is_set(), "the TUI never showed the service's state"
            service.wait_windows(1)
            subprocess.run([*tmux, "send-keys", "-t", "t", "q"], check=True)
            gone = threading.Event()
            for _ in range(300):
                has = subprocess.run([*tmux, "has-session", "-t", "t"], capture_output=True)
                if has.returncode != 0:
                    gone.set()
                    break
                gone.wait(0.1)
            assert gone.is_set()
        finally:
            subprocess.run([*tmux, "kill-server"], capture_output=True)
        service.wait_windows(2)
        assert service.alive


def test_a_second_service_on_the_same_state_directory_is_refused(
    service: ServiceProcess, cell: Path
) -> None:
    out = rvis(
        "run", "--sim", "--geometric", "--cell", str(cell), "--state-dir", str(service.state_dir)
    )
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert str(service.state_dir) in line and f"pid {service.proc.pid}" in line
    assert service.alive and status(service.state_dir)["state"] in ("idle", "measuring")


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_kill_9_at_random_points_keeps_every_row_and_the_recalibration_progress(
    tmp_path: Path, cell: Path
) -> None:
    """Restarts more often than every 24 measurements: calibrations still happen. Every
    measurement the service announced before the kill (it announces a row once committed) is
    in the database after it, and a temporary file of a write cut short (planted after each
    kill, as a kill inside an atomic write leaves one) is gone after the next start."""
    state = tmp_path / "state"
    rng = np.random.default_rng(19)
    stored = 0
    left: list[Path] = []  # temporary files of a write the kill cut short
    decided: dict = {}
    for k in range(5):
        svc = ServiceProcess(state, cell)
        svc.wait_ready()
        assert left == [] or not [f for f in left if f.exists()]  # the start removed them
        if k == 4:  # as a calibration is decided: killed around its apply
            decided = svc.wait_log(lambda r: r.get("event") == "calibration", 60.0)["data"]
        else:
            svc.wait_windows(int(rng.integers(5, 9)))
            svc.wait_log(lambda r: r.get("event") in ("measurement", "state", "window"), 10.0)
        svc.kill9()
        db = state / "rvis.db"
        now = count(db, "SELECT COUNT(*) FROM measurements")
        assert now >= stored  # nothing stored is ever lost
        assert svc.logged_ids, "no measurement announced before the kill"
        ids = ",".join(map(str, svc.logged_ids))
        found = count(db, f"SELECT COUNT(*) FROM measurements WHERE id IN ({ids})")
        assert found == len(set(svc.logged_ids)), (max(svc.logged_ids), now)
        con = sqlite3.connect(db)
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        con.close()
        stored = now
        left = list((state / "params").rglob(".*.tmp"))
        for folder in (state / "params", state / "params" / "history"):
            planted = folder / f".planted-{k}.json.tmp"
            planted.write_text("{")  # half a document: what a kill inside a write leaves
            left.append(planted)
    assert stored >= 24
    svc = ServiceProcess(state, cell)  # and it still runs, the apply completed
    try:
        svc.wait_ready()
        svc.wait_windows(2)
        assert left and not [f for f in left if f.exists()]  # the start removed them
    finally:
        code = svc.stop()
    assert code == 0, svc.errors()
    # the calibration announced before the last kill: stored, and decided as auto mode decides
    # it (one that passed its gates applied once, at once or at the restart; a rejected one
    # never)
    db, cal_id = state / "rvis.db", int(decided["id"])
    passed = decided["status"] == "pending"
    status_now = "applied" if passed else "rejected"
    row = f"SELECT COUNT(*) FROM calibrations WHERE id = {cal_id} AND status = '{status_now}'"
    assert count(db, row) == 1, decided
    assert count(db, f"SELECT COUNT(*) FROM applied WHERE calibration_id = {cal_id}") == passed
    doc = json.loads((state / "params" / "current.json").read_text())
    assert count(state / "rvis.db", "SELECT MAX(version) FROM applied") == doc["history_version"]


def test_a_damaged_database_is_refused_with_one_line(tmp_path: Path, cell: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    (state / "rvis.db").write_bytes(b"garbage" * 1000)
    out = rvis("run", "--sim", "--geometric", "--cell", str(cell), "--state-dir", str(state))
    assert out.returncode == 2
    (line,) = out.stderr.strip().splitlines()
    assert "rvis.db" in line and "damaged" in line and "rvis state backup" in line
    assert (state / "rvis.db").read_bytes() == b"garbage" * 1000


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_a_damaged_current_json_is_rebuilt_with_an_alarm(tmp_path: Path, cell: Path) -> None:
    state = tmp_path / "state"
    svc = ServiceProcess(state, cell)
    svc.wait_ready()
    assert svc.stop() == 0
    (state / "params" / "current.json").write_text("{ not json")
    svc = ServiceProcess(state, cell)
    try:
        svc.wait_ready()
        codes = [a["code"] for a in status(state)["alarms"]]
        assert "params_rebuilt" in codes
        json.loads((state / "params" / "current.json").read_text())
    finally:
        assert svc.stop() == 0


def _as_nobody(setpriv: str) -> list[str]:
    return [setpriv, "--reuid=nobody", "--regid=nogroup", "--clear-groups", sys.executable]


def _nobody_can(setpriv: str, code: str, cwd: Path) -> bool:
    argv = [*_as_nobody(setpriv), "-c", code]
    return subprocess.run(argv, capture_output=True, cwd=cwd, timeout=60).returncode == 0


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to drop to another user")
def test_an_unusable_state_directory_is_refused_with_one_line(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)  # root's, and its parents too: another user cannot reach it
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("setpriv not installed")
    cwd = ROOT
    if not _nobody_can(setpriv, "import app", cwd):
        # a checkout under a directory only root may enter: the sources copied where nobody
        # reads them (the interpreter must be reachable: a virtualenv inside such a checkout
        # is not, and then the test cannot run as another user)
        if not _nobody_can(setpriv, "pass", Path("/")):
            pytest.skip(f"{sys.executable} is not reachable by the user nobody")
        cwd = Path(tempfile.mkdtemp(prefix="rvis-src-", dir="/tmp"))
        cwd.chmod(0o755)
        for package in ("app", "calib", "vision", "drivers", "fakes"):
            shutil.copytree(ROOT / package, cwd / package)
        subprocess.run(["chmod", "-R", "a+rX", str(cwd)], check=True)
    try:
        argv = [*_as_nobody(setpriv), "-m", "app", "run", "--sim", "--geometric"]
        argv += ["--state-dir", str(state)]
        out = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, timeout=60)
    finally:
        if cwd != ROOT:
            shutil.rmtree(cwd, ignore_errors=True)
    assert out.returncode == 2, out.stderr
    (line,) = out.stderr.strip().splitlines()
    assert str(state) in line and "permission denied" in line.lower()


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("mount") is None, reason="needs root")
def test_a_full_disk_faults_the_cell_and_the_service_stays_up(tmp_path: Path, cell: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(state)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip("cannot mount a tmpfs here (tests/line/test_restart.py covers the seam)")
    svc = ServiceProcess(state, cell)
    try:
        svc.wait_ready()
        ballast = state / "ballast"
        # fill the disk to the last byte, unbuffered: a buffered file would try to write the rest
        # of its buffer again when it closes, and raise ENOSPC there
        with open(ballast, "wb", buffering=0) as fh, contextlib.suppress(OSError):
            while True:
                fh.write(b"\0" * 65536)
        svc.wait_log(lambda r: r.get("event") == "alarm" and r["data"]["code"] == "state_storage")
        st = status(state)  # the service answers
        assert st["state"] == "fault" and svc.alive
        refused = rvis("ctl", "--state-dir", str(state), "reset")
        assert refused.returncode != 0 and "still fails" in refused.stderr + refused.stdout
        ballast.unlink()
        reset = rvis("ctl", "--state-dir", str(state), "reset")
        assert reset.returncode == 0, reset.stderr
        svc.wait_log(lambda r: r.get("event") == "measurement", 30.0)
        assert svc.alive
    finally:
        svc.stop()
        subprocess.run(["umount", "-l", str(state)], capture_output=True)


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_a_backup_taken_while_running_restores_to_a_service_that_carries_on(
    service: ServiceProcess, tmp_path: Path, cell: Path
) -> None:
    backup = tmp_path / "backup"
    out = rvis("state", "backup", str(backup), "--state-dir", str(service.state_dir), "--json")
    assert out.returncode == 0, out.stderr
    manifest = json.loads(out.stdout)
    assert manifest["integrity"] == ["ok"] and manifest["applied_version"] >= 1
    # (a directory the simulated line made keeps its cell's record, app.sim.world_record)
    names = sorted(p.name for p in backup.iterdir())
    assert names == ["backup.json", "params", "rvis.db", "simulation.json"]
    assert stat.S_IMODE(backup.joinpath("rvis.db").stat().st_mode) & 0o007 == 0
    again = rvis("state", "backup", str(backup), "--state-dir", str(service.state_dir))
    assert again.returncode == 2 and "not an empty folder" in again.stderr
    refused = rvis("state", "restore", str(backup), "--state-dir", str(service.state_dir))
    assert refused.returncode == 2 and f"(pid {service.proc.pid})" in refused.stderr
    taken = manifest["measurements"]["ok"] + manifest["measurements"]["rejected"]

    restored = tmp_path / "restored"
    assert rvis("state", "restore", str(backup), "--state-dir", str(restored)).returncode == 0
    check = rvis("state", "check", "--state-dir", str(restored), "--json")
    assert check.returncode == 0, check.stdout
    assert json.loads(check.stdout)["parameters"]["current_version"] == manifest["applied_version"]
    svc = ServiceProcess(restored, cell)
    try:
        svc.wait_ready()
        row = svc.wait_log(lambda r: r.get("event") == "measurement", 30.0)
        assert row["data"]["id"] > taken  # the restored history goes on
    finally:
        assert svc.stop() == 0


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_state_check_names_what_is_wrong(tmp_path: Path, cell: Path) -> None:
    state = tmp_path / "state"
    svc = ServiceProcess(state, cell)
    svc.wait_ready()
    assert svc.stop() == 0
    ok = rvis("state", "check", "--state-dir", str(state))
    assert ok.returncode == 0 and "result           ok" in ok.stdout
    (state / "params" / "current.json").write_text("{ not json")
    os.chmod(state / "rvis.db", 0o644)
    found = rvis("state", "check", "--state-dir", str(state), "--json")
    assert found.returncode == 1
    problems = json.loads(found.stdout)["problems"]
    assert any("current.json: unreadable" in p for p in problems)
    assert any("rvis.db: mode 0644 gives others access" in p for p in problems)
    (state / "rvis.db").write_bytes(b"garbage" * 1000)
    damaged = rvis("state", "check", "--state-dir", str(state))
    assert damaged.returncode == 1 and "damaged" in damaged.stdout
    missing = rvis("state", "check", "--state-dir", str(tmp_path / "nowhere"))
    assert missing.returncode == 2 and "no such state directory" in missing.stderr


def test_a_damaged_database_file_is_named_whatever_its_write_ahead_log_holds(
    tmp_path: Path,
) -> None:
    """Garbage over `rvis.db` while a write-ahead log beside it still holds every page (a
    reader kept it from being folded in): SQLite reads the pages from the log and finds no
    fault, but the file is damaged, and `state check` says so from its header."""
    from app.commands.state_check import check
    from app.line.statedir import StateDir
    from app.line.store import Store

    state = StateDir(tmp_path / "state")
    state.root.mkdir()
    store = Store(state.db)
    reader = sqlite3.connect(state.db)
    reader.execute("BEGIN")
    reader.execute("SELECT count(*) FROM measurements").fetchall()  # holds the log
    store.close()
    wal, shm = (state.db.with_name(state.db.name + s) for s in ("-wal", "-shm"))
    kept = {p: p.read_bytes() for p in (wal, shm)}
    assert len(kept[wal]) > 0
    reader.close()
    state.db.write_bytes(b"garbage" * 1000)
    for p, data in kept.items():
        p.write_bytes(data)
    problems = check(state, 0.0, "")["problems"]
    assert any("rvis.db: damaged" in p for p in problems), problems


def _children(pid: int) -> list[int]:
    """The child processes of `pid`, whichever of its threads started them."""
    tasks = Path(f"/proc/{pid}/task")
    return [int(c) for t in tasks.iterdir() for c in (t / "children").read_text().split()]


def _identification_worker(service_pid: int) -> int | None:
    """The worker process of the service's identification (a child of its forkserver)."""
    for child in _children(service_pid):
        cmdline = Path(f"/proc/{child}/cmdline").read_bytes()
        if b"forkserver" in cmdline:
            workers = _children(child)
            return workers[0] if workers else None
    return None


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_a_worker_killed_by_the_system_faults_the_cell_and_the_supervisor_restarts_it(
    tmp_path: Path, cell: Path
) -> None:
    """The identification worker dies (the OOM killer): the service logs the error with its
    traceback, raises an urgent alarm, puts the cell in FAULT and exits 1; restarted, it holds
    the FAULT until an operator's reset, then measures again."""
    state = tmp_path / "state"
    svc = ServiceProcess(state, cell)
    svc.wait_ready()
    svc.wait_log(lambda r: r.get("event") == "recalibration_started", 60.0)
    worker = _identification_worker(svc.proc.pid)
    assert worker is not None
    os.kill(worker, 9)
    line = svc.wait_log(lambda r: r.get("event") == "internal_error", 60.0)
    assert "BrokenProcessPool" in line["msg"] and "Traceback" in line["exc"]
    svc.wait_log(lambda r: r.get("event") == "alarm" and r["data"]["code"] == "internal_error")
    assert svc.proc.wait(60) == 1
    svc.stop()
    svc = ServiceProcess(state, cell)
    try:
        # the start holds the fault from before after its `started` event: wait for that
        svc.wait_log(lambda r: r.get("event") == "state" and r["data"]["to"] == "fault", 60.0)
        st = status(state)
        assert st["state"] == "fault"
        assert [a["code"] for a in st["alarms"] if a["priority"] == "urgent"] == ["internal_error"]
        reset = rvis("ctl", "--state-dir", str(state), "reset")
        assert reset.returncode == 0, reset.stderr
        svc.wait_log(lambda r: r.get("event") == "measurement", 30.0)
    finally:
        code = svc.stop()
    assert code == 0, svc.errors()


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_stop_signal_to_the_whole_group_during_a_calibration_is_a_clean_stop(
    tmp_path: Path, cell: Path, sig: signal.Signals
) -> None:
    """systemd's stop (SIGTERM to every process of the unit) or Ctrl-C in a terminal (SIGINT to
    the process group) while the identification worker runs: only the service acts on it, the
    calibration in flight ends, and the exit is 0 (not an internal error in FAULT)."""
    svc = ServiceProcess(tmp_path / "state", cell)
    try:
        svc.wait_ready()
        svc.wait_log(lambda r: r.get("event") == "recalibration_started", 60.0)
        os.killpg(svc.proc.pid, sig)
        code = svc.wait_exit(60.0)  # this signal alone ends it: nothing sent again
        assert code == 0, svc.errors()
    finally:
        if svc.alive:  # (a failed wait: the service is not left running for the next tests)
            svc.kill9()


def test_ctrl_c_in_a_counted_simulated_run_ends_with_its_figures(
    tmp_path: Path, cell: Path
) -> None:
    """`rvis run --sim --windows N` stopped by Ctrl-C (SIGINT to the process group) after a few
    windows: exit 0 and the summary of what ran, its true RMSE at the end a number (it was nan:
    the parameters in force when stopped were never put against the truth)."""
    argv = [*RVIS, "run", "--sim", "--geometric", "--windows", "100000", "--cell", str(cell)]
    svc = ServiceProcess(tmp_path / "state", cell, argv)
    try:
        for _ in range(3):
            svc.wait_log(lambda r: r.get("event") == "sim_window", 60.0)
        os.killpg(svc.proc.pid, signal.SIGINT)
        code = svc.wait_exit(60.0)
        assert code == 0, svc.errors()
        (line,) = [t for t in svc.stderr.splitlines() if "mm at the end" in t]
        end = line.rsplit("true RMSE", 1)[1]
        assert "nan" not in end, line
        final = float(end.split(" mm at the start, ", 1)[1].split(" mm")[0])
        assert 0.0 < final < 0.3, line
    finally:
        if svc.alive:
            svc.kill9()
