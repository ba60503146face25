"""Tracker contract: one test body per behaviour, run on fake://, the TCP side-car peer, the CSV
import and a real side-car (``RVIS_TRACKER_URL``); then the side-car fault tests (the peer's)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers import (
    DeviceConfigError,
    DeviceConnectionError,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
    open_tracker,
)
from drivers.tracker import Tracker
from drivers.tracker_tcp import TcpTracker
from fakes.tracker_service import E_NOT_IN_BEAM, TrackerService
from fakes.world import StaticWorld
from tests.drivers.backends import HARDWARE, backends, real_url


def write_csv(path: Path, world: StaticWorld) -> None:
    lines = ["target,x_mm,y_mm,z_mm,rms_mm"]
    for t in world.target_ids():
        x, y, z = world.target_true_mm(t)
        lines.append(f"{t},{x},{y},{z},0.004")
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(params=backends("tracker", ["fake", "tcp", "file"]))
def backend(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def tracker(backend: str, world: StaticWorld, tmp_path: Path) -> Iterator[Tracker]:
    with ExitStack() as stack:
        opts: dict[str, Any]
        if backend == HARDWARE:
            url, opts = real_url("tracker"), {"timeout_s": 60.0}
        elif backend == "fake":
            url, opts = "fake://", {"world": world, "seed": 3, "timeout_s": 1.0}
        elif backend == "tcp":
            svc = stack.enter_context(TrackerService(world, seed=3))
            url, opts = f"tracker+tcp://127.0.0.1:{svc.port}", {"timeout_s": 1.0}
        else:
            write_csv(tmp_path / "targets.csv", world)
            url, opts = f"tracker+file://{tmp_path / 'targets.csv'}", {"timeout_s": 1.0}
        yield stack.enter_context(open_tracker(url, **opts))


def test_measures_every_target(tracker: Tracker, backend: str, world: StaticWorld) -> None:
    targets = tracker.targets()
    assert targets and len(set(targets)) == len(targets)
    if backend != HARDWARE:
        assert targets == world.target_ids()
    for t in targets:
        m = tracker.measure(t)
        assert m.target_id == t and m.point_mm.shape == (3,) and np.all(np.isfinite(m.point_mm))
        assert 0 <= m.rms_mm <= tracker.max_rms_mm and 800 < m.pressure_hpa < 1100
        if backend != HARDWARE:
            np.testing.assert_allclose(m.point_mm, world.target_true_mm(t), atol=0.02)
    assert tracker.status().ready
    assert tracker.describe()


def test_repeated_measurements_agree_within_their_rms(tracker: Tracker) -> None:
    first = tracker.targets()[0]
    a, b = tracker.measure(first), tracker.measure(first)
    spread = max(a.rms_mm, b.rms_mm, 0.002)
    assert np.linalg.norm(a.point_mm - b.point_mm) <= 5 * spread


def test_unknown_target_is_a_device_fault(tracker: Tracker) -> None:
    with pytest.raises(DeviceFault):
        tracker.measure("no-such-target-0000")
    with pytest.raises(DeviceConfigError):
        tracker.measure("")


@pytest.fixture
def svc(world: StaticWorld) -> Iterator[TrackerService]:
    with TrackerService(world) as s:
        yield s


@pytest.fixture
def tcp(svc: TrackerService) -> Iterator[TcpTracker]:
    with TcpTracker("127.0.0.1", svc.port, timeout_s=0.3) as t:
        yield t


def test_target_not_in_beam(svc: TrackerService, tcp: TcpTracker) -> None:
    svc.in_beam = False
    assert not tcp.status().target_in_beam
    with pytest.raises(DeviceFault, match="not in beam") as info:
        tcp.measure("S1")
    assert info.value.code == E_NOT_IN_BEAM


def test_noisy_point_fails_the_quality_gate(world: StaticWorld) -> None:
    with (
        TrackerService(world, noise_mm=0.5) as svc,
        TcpTracker("127.0.0.1", svc.port, max_rms_mm=0.05) as t,
        pytest.raises(DeviceFault, match="RMS"),
    ):
        t.measure("S1")


@pytest.mark.parametrize("mode", ["drop", "garble", "truncate"])
def test_broken_replies_are_retried_once_after_reconnect(
    svc: TrackerService, tcp: TcpTracker, mode: str
) -> None:
    svc.fail_next("measure", mode)
    assert tcp.measure("S2").target_id == "S2"
    assert sum(r["cmd"] == "hello" for r in svc.requests) == 2


def test_side_car_silence_is_a_timeout(svc: TrackerService, tcp: TcpTracker) -> None:
    svc.fail_next("status", "mute")
    with pytest.raises(DeviceTimeout):
        tcp._status()


def test_side_car_error_code(svc: TrackerService, tcp: TcpTracker) -> None:
    svc.fail_next("targets", 77)
    with pytest.raises(DeviceFault) as info:
        tcp.targets()
    assert info.value.code == 77


def test_protocol_mismatch(svc: TrackerService) -> None:
    svc.fail_next("hello", 5)
    with pytest.raises(DeviceFault):
        TcpTracker("127.0.0.1", svc.port).open()
    bad = TcpTracker("127.0.0.1", svc.port)
    svc.fail_next("hello", "garble")
    with pytest.raises(ProtocolError):
        bad.open()


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("target,x_mm,y_mm\nS1,1,2\n", ":1: field 'z_mm'"),
        ("target,x_mm,y_mm,z_mm\nS1,1,2,abc\n", ":2: field 'z_mm'"),
        ("target,x_mm,y_mm,z_mm\nS1,1,2,3\nS1,1,2,3\n", ":3: field 'target'"),
        ("target,x_mm,y_mm,z_mm\n,1,2,3\n", ":2: field 'target'"),
    ],
)
def test_bad_csv_names_file_line_and_field(tmp_path: Path, text: str, where: str) -> None:
    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(DeviceConfigError, match=where):
        open_tracker(f"tracker+file://{path}")


def test_missing_csv(tmp_path: Path) -> None:
    with pytest.raises(DeviceConfigError, match="cannot read"):
        open_tracker(f"tracker+file://{tmp_path / 'none.csv'}")


def test_side_car_gone_and_back(world: StaticWorld) -> None:
    svc = TrackerService(world).start()
    try:
        with TcpTracker("127.0.0.1", svc.port, timeout_s=0.3) as tcp:
            port = svc.port
            svc.close()
            with pytest.raises(DeviceConnectionError):
                tcp.measure("S1")  # the retry's reconnect is refused too
            with pytest.raises(DeviceConnectionError):
                tcp.status()  # no socket left: still typed
            svc = TrackerService(world, port=port).start()
            assert tcp.measure("S1").target_id == "S1"  # reconnected
    finally:
        svc.close()
