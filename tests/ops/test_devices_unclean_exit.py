"""`rvis devices sim` starts again in its folder after an unclean exit (issue 51, item 1): a
galvo link left by a killed devices process (kill -9) is replaced, never followed into the pty
it names (`Operation not permitted: '/dev/pts/1' -> '/dev/pts/1.new'` before); a devices
process waiting for another simulation's camera address says at once which process holds it,
and a SIGTERM while it waits closes what it had started (the galvo's link removed).

The pty a leftover link names is a live one of this test's (after a kill -9 the number is
given to the next terminal): it must come out untouched. The camera's address is held by a
GigE fake camera in this process (the test worker's network namespace, which the devices
process inherits). Waits are on the devices' output lines, each with a deadline."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.groups import GIGE_CAMERA
from tests.ops.test_simulated_devices import CELL, DevicesProcess

pytestmark = GIGE_CAMERA


@pytest.fixture
def base(tmp_path: Path) -> Path:
    path = tmp_path / "base.toml"
    path.write_text(CELL, encoding="utf-8")
    return path


@pytest.fixture
def other_pty() -> Iterator[str]:
    """A pty of another program's (its path, /dev/pts/N), open while the test runs."""
    master, slave = os.openpty()
    try:
        yield os.ttyname(slave)
    finally:
        os.close(slave)
        os.close(master)


def test_a_galvo_link_left_by_a_kill_9_is_replaced_never_followed(
    tmp_path: Path, base: Path, other_pty: str
) -> None:
    folder = tmp_path / "sim"
    folder.mkdir()
    (folder / "galvo").symlink_to(other_pty)  # what a killed devices process leaves
    before = os.stat(other_pty)
    devices = DevicesProcess(folder, base)
    try:
        up = devices.ready()
        assert up["devices"]["galvo"]["url"] == f"scpi+serial://{folder.resolve() / 'galvo'}"
        ours = os.readlink(folder / "galvo")
        assert ours != other_pty and os.path.exists(ours)
        assert devices.ctl("status")["devices"]["galvo"]["state"] == "up"
    finally:
        code, err = devices.stop()
    assert code == 0, err
    assert "Traceback" not in err
    assert not os.path.lexists(folder / "galvo")  # removed at the end
    after = os.stat(other_pty)  # the other program's pty: not renamed, not written
    assert (after.st_ino, after.st_mode, after.st_mtime_ns) == (
        before.st_ino,
        before.st_mode,
        before.st_mtime_ns,
    )
    assert not os.path.lexists(f"{other_pty}.new")


def test_waiting_for_the_camera_names_its_holder_and_a_sigterm_then_exits_clean(
    tmp_path: Path, base: Path
) -> None:
    from fakes.gv_camera import GvCamera

    folder = tmp_path / "sim"
    with GvCamera(address="127.0.0.1"):  # another simulation's camera holds the address
        devices = DevicesProcess(folder, base)
        try:
            line = devices.said("waiting for the simulated GigE camera's address 127.0.0.1")
            assert f"pid {os.getpid()} (" in line  # this process, with its command line
            assert os.path.islink(folder / "galvo")  # started before the camera
            code = devices.terminate()
        finally:
            devices.stop()
    assert code == 128 + signal.SIGINT  # an interruption while starting (as Ctrl-C)
    assert "Traceback" not in (devices.stderr or "")
    assert not os.path.lexists(folder / "galvo")
    assert not (folder / "devices.sock").exists()
    # the camera free: it starts in the same folder
    again = DevicesProcess(folder, base)
    try:
        assert set(again.ready()["devices"]) == {"robot", "camera", "galvo", "tracker", "plc"}
    finally:
        code, err = again.stop()
    assert code == 0, err
