"""A restarted service behaves as one that never stopped (issue 19): the same measurements,
the same calibrations on the same rows, the same parameters; a calibration in flight at the stop
runs again on its rows; storage faults are typed faults the service survives."""

from __future__ import annotations

import queue
import sqlite3
from collections.abc import Callable
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.config.line import RecalibSettings
from app.errors import InputError
from app.line.measure import GeometricSensor
from app.line.params_store import ParamsStore
from app.line.recalib import Recalibrator
from app.line.statedir import StateDir
from app.line.store import DatabaseDamaged, Store
from fakes.cell import SimulatedCell
from fakes.devices import ClampCycle
from tests.line.helpers import SCALE, Line, line_settings, make_line

SEED = 5
NOISE_MM = 0.02


class InlineExecutor(Executor):
    """Runs each job at submission: recalibrations finish at once, so two runs on the same
    measurements decide the same (no race with the worker process)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        future: Future[Any] = Future()
        future.set_result(fn(*args, **kwargs))
        return future


class NeverExecutor(Executor):
    """Accepts a job and never runs it: a calibration in flight when the service stops."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        return Future()


def keyed_sensor(state_dir: Path) -> Callable[[SimulatedCell], GeometricSensor]:
    """The cell's noise-free centre plus noise drawn from the measurement's number (the rows
    stored before it + 1): two runs on the same seed measure exactly alike, restarted or not."""

    def build(cell: SimulatedCell) -> GeometricSensor:
        db = state_dir / "rvis.db"
        count = [0]
        if db.exists():
            con = sqlite3.connect(db)
            count[0] = int(con.execute("SELECT COUNT(*) FROM measurements").fetchone()[0])
            con.close()

        def centre(target: str) -> np.ndarray:
            count[0] += 1
            noise = np.random.default_rng([SEED, count[0]]).normal(0.0, NOISE_MM, 3)
            return np.asarray(cell.measure_target(target)) + noise

        return GeometricSensor(centre, duration_s=1.2)

    return build


def run_line(state_dir: Path, windows: int, executor: type[Executor] = InlineExecutor) -> None:
    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    ln = make_line(
        state_dir,
        seed=SEED,
        cycle=cycle,
        line=line_settings(window_s=32.0, slots_per_window=8),
        # the recalibrations' candidate the estimator's posterior (the default): no drift as
        # process noise, because the restarted runs' clock has gaps the one run has not (a
        # stopped cell may have drifted meanwhile: its estimator rightly widens by the gap)
        recalib=RecalibSettings(
            every_n=8,
            estimator="batch",
            rolling_size=24,
            jump_drift_mm_per_h=0.0,
            jump_drift_rad_per_h=0.0,
        ),
        sensor=keyed_sensor(state_dir),
        sensor_noise_mm=0.0,
        # the keyed noise stands in for every non-repeatable error: a new cell per restart
        # would start the robot's stops (seeded per joints and visit) afresh
        repeatability_mm=0.0,
    )
    ln.service.recalibrator = Recalibrator(executor)
    # after each window (its recalibration submitted, if one was due): is one in flight?
    in_flight: queue.Queue[bool] = queue.Queue()
    ln.service.after_window = lambda: in_flight.put(ln.service.decision.recal_ids is not None)
    try:
        ln.start()
        ln.windows(windows, timeout_s=30.0)
        last = [in_flight.get(timeout=30.0) for _ in range(windows)][-1]
        if last and executor is InlineExecutor:
            # its decision, the loop's next pass: stopped before it, the run would leave it
            # for its next start to run again (the test below), and the two runs would differ
            # by when the stop came, not by what they decided
            ln.wait(lambda e: e["event"] == "calibration", 30.0)
    finally:
        ln.close()


def decisions(state_dir: Path) -> dict[str, Any]:
    store = Store.read_only(state_dir / "rvis.db")
    try:
        rows = store.measurements()
        cals = store.calibrations()
        return {
            "measurements": [(r["slot"], r["target"], r["c_sensor_mm"]) for r in rows],
            "calibrations": [(c["first_id"], c["last_id"], c["status"]) for c in cals],
            "x": [
                [p["value"] for p in c["document"]["parameters"]]
                for c in cals
                if c["document"] is not None
            ],
            "applied": [(a["version"], a["calibration_id"]) for a in store.applied()],
            "alarms": sorted(a["code"] for a in store.alarms()),
        }
    finally:
        store.close()


@pytest.mark.slow  # started first on a worker (tests/conftest.py)
def test_a_restarted_service_decides_as_one_that_never_stopped(tmp_path: Path) -> None:
    once, restarted = tmp_path / "once", tmp_path / "restarted"
    run_line(once, 9)
    for part in (3, 2, 4):  # clean stops, each shorter than a rolling set of 24
        run_line(restarted, part)
    a, b = decisions(once), decisions(restarted)
    assert len(a["measurements"]) == 72 and len(a["calibrations"]) >= 3
    assert b["measurements"] == a["measurements"]
    assert b["calibrations"] == a["calibrations"]
    # the restarted estimator replays its version's measurements (the one run took them one
    # at a time): the same posterior to the sums' rounding
    np.testing.assert_allclose(np.array(b["x"]), np.array(a["x"]), rtol=0, atol=1e-6)
    assert b["applied"] == a["applied"] and b["alarms"] == a["alarms"]


def test_a_calibration_in_flight_at_a_stop_runs_again_on_its_rows(tmp_path: Path) -> None:
    run_line(tmp_path, 4, executor=NeverExecutor)  # 32 measurements: one job submitted, lost
    store = Store.read_only(tmp_path / "rvis.db")
    state = store.load_state()
    assert state is not None and state["recal_ids"] is not None
    ids = state["recal_ids"]
    assert store.calibrations() == []
    store.close()
    run_line(tmp_path, 1)
    store = Store.read_only(tmp_path / "rvis.db")
    first = store.calibrations()[0]
    store.close()
    assert (first["first_id"], first["last_id"]) == (ids["train"][0], ids["holdout"][-1])


def test_a_damaged_database_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    db = StateDir(tmp_path).db
    db.write_bytes(b"this is not an SQLite database, it is a shopping list\n" * 100)
    before = db.read_bytes()
    with pytest.raises(DatabaseDamaged, match="damaged") as err:
        Store(db)
    assert isinstance(err.value, InputError) and err.value.exit_code == 2
    assert db.read_bytes() == before and not Path(f"{db}-wal").exists()


def test_a_damaged_current_json_is_rebuilt_from_the_history(tmp_path: Path) -> None:
    run_line(tmp_path, 5)  # 40 measurements, a calibration applied: version 2 (or 3 when the
    # paced line ran a window more before it closed, on a loaded machine)
    version = ParamsStore(tmp_path).current_version()
    assert version is not None and version >= 2
    paths = StateDir(tmp_path)
    good = ParamsStore(tmp_path).version_path(version).read_bytes()
    paths.current.write_text('{"format": "rvis-params", "trunc')
    ln: Line = make_line(tmp_path, seed=SEED)
    try:
        assert ln.service.version == version
        assert paths.current.read_bytes() == good
        ln.start()
        alarm = ln.wait(lambda e: e["event"] == "alarm" and e["code"] == "params_rebuilt")
        assert "damaged" in alarm["message"] and f"history {version}" in alarm["message"]
    finally:
        ln.close()
    paths.current.unlink()  # missing: the same
    ln = make_line(tmp_path, seed=SEED)
    ln.close()
    assert paths.current.read_bytes() == good


def test_a_full_database_faults_the_cell_until_space_is_back_and_a_reset(tmp_path: Path) -> None:
    ln = make_line(tmp_path, seed=SEED)
    ln.start()
    try:
        ln.windows(1)
        db = ln.service.store._db  # the seam: SQLite's own "database or disk is full"
        with ln.service.store._lock:
            pages = int(db.execute("PRAGMA page_count").fetchone()[0])
            db.execute(f"PRAGMA max_page_count = {pages}")
        ln.wait(lambda e: e["event"] == "alarm" and e["code"] == "state_storage", 15.0)
        acked = len(ln.plc.rows_at_done)
        status = ln.service.status()
        (alarm,) = [a for a in status["alarms"] if a["code"] == "state_storage"]
        assert "full" in alarm["message"] and alarm["priority"] == "urgent"
        assert ln.plc.received.fault
        assert ln.plc.rows_at_done[-1] <= ln.service.store.counts()["ok"]  # acked: committed
        ln.plc.wait_edges(2)  # windows open and pass: nothing measured, nothing acknowledged
        assert len(ln.plc.rows_at_done) == acked and ln.service.status()["state"] == "fault"
        assert ln.service.request("reset").result(10)["ok"] is False  # still full
        with ln.service.store._lock:
            db.execute("PRAGMA max_page_count = 1073741823")
        reply = ln.service.request("reset").result(10)
        assert reply["ok"], reply
        ln.windows(2)
        assert len(ln.plc.rows_at_done) > acked
        stored = [a["code"] for a in ln.service.store.alarms()]
        assert "state_storage" in stored  # the alarm reached the database once it could
    finally:
        ln.close()


def test_a_device_fault_held_from_before_a_restart_leaves_the_devices_ok(tmp_path: Path) -> None:
    """A fault alarm in force when the service stopped is held at its restart until a reset
    (issue 51): the devices were opened afresh and answer, so none of them is shown "fault"
    (every one was, with no error, before); the held alarm says what happened before."""
    ln = make_line(tmp_path, seed=SEED)
    t = ln.clock.time()
    message = "camera (aravis://127.0.0.1): DeviceTimeout: grab: no frame"
    ln.service.store.raise_alarm(t, "device_fault", message, "urgent")  # from the last run
    ln.start()
    try:
        ln.wait(lambda e: e["event"] == "state" and e["to"] == "fault", 15.0)
        status = ln.service.status()
        assert status["state"] == "fault"
        assert [a["message"] for a in status["alarms"]] == [message]
        devices = status["devices"]
        assert {family: d["state"] for family, d in devices.items()} == {
            "plc": "ok",
            "robot": "ok",
        }
        assert all(d["last_error"] is None for d in devices.values())
        reply = ln.service.request("reset").result(10)
        assert reply["ok"], reply
        ln.windows(1)
    finally:
        ln.close()
