"""The contract suites' real-device runs, exercised: the suites run in a child pytest with
``RVIS_<FAMILY>_URL`` pointing at the protocol peers on 127.0.0.1 (as a commissioning engineer
points them at the cell's devices) and ``-m hardware``, so that the code path a real device
takes (the safety profile, the read-back checks, the read-only PLC) is not dead code."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest

from fakes.devices import ClampCycle
from fakes.world import StaticWorld
from tests.groups import GIGE_CAMERA

pytestmark = GIGE_CAMERA

ROOT = Path(__file__).resolve().parents[2]
SUITES = [
    "tests/drivers/test_robot_contract.py",
    "tests/drivers/test_plc_contract.py",
    "tests/drivers/test_galvo.py",
    "tests/drivers/test_tracker.py",
    "tests/drivers/test_camera.py",
]


@pytest.fixture
def peer_urls() -> Iterator[dict[str, str]]:
    from fakes.plc import PlcServer
    from fakes.rmi_controller import RmiController
    from fakes.scpi_dac import ScpiDac
    from fakes.tracker_service import TrackerService

    world = StaticWorld()
    with ExitStack() as stack:
        rmi = stack.enter_context(RmiController(world, time_scale=0.01))
        # a 60 s clamp cycle with an 8 s window, 50x faster; the heartbeat every 10 ms
        plc = stack.enter_context(PlcServer(ClampCycle(60.0, 8.0, 0.5, time_scale=0.02)))
        dac = stack.enter_context(ScpiDac())
        trk = stack.enter_context(TrackerService(world, seed=5))
        urls = {
            "RVIS_ROBOT_URL": f"rmi://127.0.0.1:{rmi.port}",
            "RVIS_PLC_URL": f"plc+modbus://127.0.0.1:{plc.port}",
            "RVIS_GALVO_URL": f"scpi+serial://{dac.port}",
            "RVIS_TRACKER_URL": f"tracker+tcp://127.0.0.1:{trk.port}",
        }
        try:
            from fakes.gv_camera import GvCamera

            gv = stack.enter_context(GvCamera(world))
            urls["RVIS_CAMERA_URL"] = f"aravis://{gv.camera_id}"
        except (ImportError, ValueError, RuntimeError):
            pass  # no Aravis here: the camera suite's real run is not exercised
        yield urls


def test_the_suites_run_on_devices_named_by_url(peer_urls: dict[str, str]) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RVIS_")}
    env |= peer_urls | {"RVIS_PLC_WRITE": "1", "RVIS_PLC_WINDOW_S": "10"}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "hardware"]
    done = subprocess.run(
        [*cmd, *SUITES], cwd=ROOT, env=env, capture_output=True, text=True, timeout=240
    )
    tail = done.stdout[-3000:] + done.stderr[-2000:]
    assert done.returncode == 0, tail
    passed = int(re.search(r"(\d+) passed", done.stdout).group(1))  # type: ignore[union-attr]
    failed = re.search(r"(\d+) failed", done.stdout)
    assert failed is None, tail
    # every family's real-device run took part: robot 12, plc 7, galvo 2, tracker 3, camera 4;
    # skipped: the fault tests that need a fake (2 controller alarms, 1 frozen heartbeat)
    expected = 12 + 7 + 2 + 3 + (4 if "RVIS_CAMERA_URL" in peer_urls else 0)
    assert passed == expected, tail
    skipped = re.search(r"(\d+) skipped", done.stdout)
    assert skipped is not None and int(skipped.group(1)) == 3, tail  # 2 alarm, 1 heartbeat
