"""The wire trace: one seam for every protocol back end (drivers/trace.py). Each back end, opened
with ``?trace=1`` against its peer, leaves its requests, replies and errors in the file; a
device not asked to trace leaves nothing; the file rotates and survives concurrent writers."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest

from drivers import DeviceConfigError, DeviceTimeout, open_device
from drivers.trace import WireTrace
from fakes.world import StaticWorld
from tests.groups import GIGE_CAMERA


def records(path: Path) -> list[dict[str, Any]]:
    return [d for line in path.read_text().splitlines() if "dir" in (d := json.loads(line))]


@pytest.fixture
def trace(tmp_path: Path) -> Iterator[WireTrace]:
    with WireTrace(tmp_path / "trace" / "wire.jsonl") as t:
        yield t


def _rmi(world: StaticWorld, stack: ExitStack) -> str:
    from fakes.rmi_controller import RmiController

    return f"rmi://127.0.0.1:{stack.enter_context(RmiController(world)).port}"


def _modbus(world: StaticWorld, stack: ExitStack) -> str:
    from fakes.modbus_robot import ModbusRobotServer

    return f"modbus://127.0.0.1:{stack.enter_context(ModbusRobotServer(world)).port}"


def _plc(world: StaticWorld, stack: ExitStack) -> str:
    from fakes.plc import PlcServer

    return f"plc+modbus://127.0.0.1:{stack.enter_context(PlcServer()).port}"


def _scpi(world: StaticWorld, stack: ExitStack) -> str:
    from fakes.scpi_dac import ScpiDac

    return f"scpi+serial://{stack.enter_context(ScpiDac()).port}"


def _tracker(world: StaticWorld, stack: ExitStack) -> str:
    from fakes.tracker_service import TrackerService

    return f"tracker+tcp://127.0.0.1:{stack.enter_context(TrackerService(world)).port}"


# family, peer, one operation, what the trace must show sent and received
CASES = {
    "rmi": ("robot", _rmi, lambda d: d.joints_deg(), "FRC_ReadJointAngles", '"JointAngle"'),
    "modbus": ("robot", _modbus, lambda d: d.joints_deg(), "fc3 read 28 count 12", "fc3 28: ["),
    "plc": ("plc", _plc, lambda d: d.poll(), "fc3 read 0 count 3", "fc16 10: ok"),
    "scpi": ("galvo", _scpi, lambda d: d.set_volts(1.25), ":SOUR:VOLT 1.250000", '0,"No error"'),
    "tracker": ("tracker", _tracker, lambda d: d.measure("S2"), '"cmd":"measure"', '"x_mm"'),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_back_end_traces_its_requests_and_replies(
    case: str, trace: WireTrace, world: StaticWorld
) -> None:
    family, peer, operation, sent, received = CASES[case]
    with ExitStack() as stack:
        url = peer(world, stack)
        device = stack.enter_context(open_device(family, f"{url}?trace=1", trace=trace))
        operation(device)
    rows = records(trace.path)
    assert rows[0] == rows[0] | {"dev": family, "dir": "!", "msg": f"traced: {device.name}"}
    assert {r["dev"] for r in rows} == {family}
    assert any(r["dir"] == ">" and sent in r["msg"] for r in rows), rows
    assert any(r["dir"] == "<" and received in r["msg"] for r in rows), rows
    times = [r["t"] for r in rows]
    assert times == sorted(times)  # monotonic


@GIGE_CAMERA
def test_the_camera_traces_its_feature_writes_and_frames(
    trace: WireTrace, world: StaticWorld
) -> None:
    pytest.importorskip("gi")
    from drivers.camera import CameraSettings
    from fakes.gv_camera import GvCamera

    settings = CameraSettings(region=(0, 0, 64, 48), exposure_us=2500.0)
    with GvCamera(world) as gv:
        url = f"aravis://{gv.camera_id}?trace=1"
        with open_device("camera", url, trace=trace, settings=settings) as cam:
            frame = cam.grab()  # type: ignore[attr-defined]
    rows = records(trace.path)
    assert any(r["dir"] == ">" and r["msg"] == "exposure(2500.0,)" for r in rows), rows
    assert any(r["dir"] == ">" and r["msg"].startswith("region(0, 0, 64, 48)") for r in rows)
    assert any(
        r["dir"] == "<" and r["msg"].startswith(f"frame {frame.frame_id} success 64x48")
        for r in rows
    ), rows


def test_errors_are_traced_too(trace: WireTrace) -> None:
    from fakes.scpi_dac import ScpiDac

    with (
        ScpiDac() as dac,
        open_device(
            "galvo", f"scpi+serial://{dac.port}?trace=1", trace=trace, timeout_s=0.2
        ) as galvo,
    ):
        dac.fail_next("SOUR:VOLT?", "mute")
        with pytest.raises(DeviceTimeout):
            galvo._get_volts()  # type: ignore[attr-defined]
    notes = [r["msg"] for r in records(trace.path) if r["dir"] == "!"]
    assert any(n.startswith("DeviceTimeout: ") and "SOUR:VOLT?" in n for n in notes), notes


def test_untraced_devices_write_nothing_and_trace_1_needs_a_file(
    trace: WireTrace, world: StaticWorld
) -> None:
    from fakes.tracker_service import TrackerService

    with TrackerService(world) as svc:
        url = f"tracker+tcp://127.0.0.1:{svc.port}"
        with open_device("tracker", url, trace=trace) as tracker:
            tracker.measure("S1")  # type: ignore[attr-defined]
        assert not trace.path.exists()
        with pytest.raises(DeviceConfigError, match="trace=1 needs a trace file"):
            open_device("tracker", f"{url}?trace=1")
        every = WireTrace(trace.path, every_device=True)
        with every, open_device("tracker", url, trace=every) as tracker:
            tracker.measure("S1")  # type: ignore[attr-defined]
        assert any(r["dev"] == "tracker" and r["dir"] == "<" for r in records(trace.path))


def test_lines_of_several_writers_land_in_the_order_of_their_times(tmp_path: Path) -> None:
    """Four threads write at once through a clock that yields right after it is read (as a
    thread may be preempted there): the file's times still never go back."""

    def yielding_clock() -> float:
        t = time.monotonic()
        time.sleep(0.0001)  # sleep-ok: a preemption right after the read, on purpose
        return t

    path = tmp_path / "wire.jsonl"
    with WireTrace(path, clock=yielding_clock) as trace:
        channels = [trace.channel(f"dev{i}") for i in range(4)]

        def writer(i: int) -> None:
            for n in range(100):
                channels[i].tx(f"request {n}")

        threads = [threading.Thread(target=writer, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    rows = records(path)
    assert len(rows) == 4 * 101 and {r["dev"] for r in rows} == {f"dev{i}" for i in range(4)}
    times = [r["t"] for r in rows]
    assert times == sorted(times)


def test_the_file_rotates_and_keeps_whole_lines(tmp_path: Path) -> None:
    path = tmp_path / "wire.jsonl"
    with WireTrace(path, max_bytes=4096, keep=3) as trace:
        channels = [trace.channel(f"dev{i}") for i in range(4)]

        def writer(i: int) -> None:
            for n in range(300):
                channels[i].tx(f"request {n} " + "x" * 40)

        threads = [threading.Thread(target=writer, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == ["wire.jsonl", "wire.jsonl.1", "wire.jsonl.2", "wire.jsonl.3"]
    for f in files:
        assert f.stat().st_size <= 4096
        lines = f.read_text().splitlines()
        assert json.loads(lines[0])["format"] == "rvis-wire/1"  # every file has its header
        assert all(json.loads(line) for line in lines)  # whole lines only
    newest = records(path)
    assert newest and all(r["msg"].startswith("request ") for r in newest)
