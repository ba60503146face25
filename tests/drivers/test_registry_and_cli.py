"""Registry (lazy imports, URL parsing, exported names) and `rvis devices check`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

import drivers
from app.commands.cli import main
from drivers import DeviceConfigError, parse_url
from drivers.registry import BACKENDS, backend_class
from tests.groups import GIGE_CAMERA


def test_import_drivers_imports_no_vendor_library() -> None:
    code = (
        "import sys, drivers, drivers.registry; "
        "print([m for m in ('pymodbus', 'serial', 'gi') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_exported_names_are_pinned() -> None:
    assert set(drivers.__all__) == {
        "CartesianBox",
        "CommunicationError",
        "DeviceClosedError",
        "DeviceConfigError",
        "DeviceConnectionError",
        "DeviceError",
        "DeviceFault",
        "DeviceTimeout",
        "Envelope",
        "FaultLatched",
        "JointBox",
        "JointLimits",
        "MotionAborted",
        "MotionRefused",
        "ProtocolError",
        "SafetyGuard",
        "create_device",
        "open_camera",
        "open_device",
        "open_galvo",
        "open_plc",
        "open_robot",
        "open_tracker",
        "parse_url",
    }


@pytest.mark.parametrize("family", sorted(BACKENDS))
def test_every_backend_resolves(family: str) -> None:
    for scheme in BACKENDS[family]:
        try:
            cls = backend_class(family, scheme)
        except DeviceConfigError as exc:  # only Aravis may be missing from a machine
            assert scheme == "aravis", exc
            continue
        assert cls.family == family


def test_url_parsing() -> None:
    u = parse_url("scpi+serial:///dev/ttyACM0?baud=115200")
    assert (u.scheme, u.path, u.number("baud", 0)) == ("scpi+serial", "/dev/ttyACM0", 115200)
    assert parse_url("tracker+file://targets.csv").location == "targets.csv"
    assert parse_url("rmi://10.0.0.5:16001").address(1) == ("10.0.0.5", 16001)
    assert parse_url("aravis://Basler-21234567").host == "Basler-21234567"
    for bad in ("robot", "rmi://h:99999"):
        with pytest.raises(DeviceConfigError):
            parse_url(bad)
    flags = parse_url("plc+modbus://h:502?read_only=1&trace=off&x=maybe")
    assert flags.flag("read_only") and not flags.flag("trace") and not flags.flag("absent")
    with pytest.raises(DeviceConfigError, match="'x' must be 1 or 0"):
        flags.flag("x")
    with pytest.raises(DeviceConfigError, match="known: rmi://, modbus://, fake://"):
        backend_class("robot", "ftp")


@GIGE_CAMERA
def test_devices_check_against_the_fakes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["devices", "check", "--json", "--timeout", "2"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {r["status"] for r in rows} <= {"OK", "SKIP"}
    assert {r["url"].split("://")[0] for r in rows} >= {
        "fake",
        "rmi",
        "modbus",
        "tracker+tcp",
        "plc+modbus",
        "scpi+serial",
    }


def test_devices_check_with_a_cell_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[devices]\nrobot = "fake://"\ntracker = "rmi://127.0.0.1:1"\n')
    assert main(["devices", "check", "--cell", str(cell)]) == 2  # rmi is not a tracker
    assert "[devices] tracker: no tracker backend for rmi://" in capsys.readouterr().err
    cell.write_text('[devices]\nrobot = "rmi://127.0.0.1:1"\nplc = "fake://"\n')
    assert main(["devices", "check", "--cell", str(cell), "--timeout", "0.5"]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "DeviceConnectionError" in out


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[devices\n", "invalid TOML"),
        ("[other]\n", "[other]: unknown section"),
        ('[devices]\nlaser = "fake://"\n', "[devices] laser: unknown key"),
        ("[devices]\nrobot = 5\n", "[devices] robot: expected a string"),
    ],
)
def test_bad_cell_file_is_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, needle: str
) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text(text)
    assert main(["devices", "check", "--cell", str(cell)]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1 and str(cell) in err
    assert main(["devices", "check", "--cell", str(tmp_path / "missing.toml")]) == 2


def test_devices_check_never_writes_the_plc(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A running service holds busy on the PLC; checking the devices leaves it so."""
    from drivers import open_plc
    from fakes.plc import PlcServer

    with PlcServer() as server, open_plc(f"plc+modbus://127.0.0.1:{server.port}") as service:
        service.set_signals(busy=True, done=False, fault=False)
        held = service.read_outputs()
        cell = tmp_path / "cell.toml"
        cell.write_text(f'[devices]\nplc = "plc+modbus://127.0.0.1:{server.port}"\n')
        assert main(["devices", "check", "--cell", str(cell)]) == 0
        assert "window" in capsys.readouterr().out
        assert service.read_outputs() == held and held.busy
        with open_plc(f"plc+modbus://127.0.0.1:{server.port}?read_only=1") as ro:
            assert ro.read_only and ro.read_outputs() == held


def test_the_drivers_alone_know_no_fake_scheme() -> None:
    """drivers/ names nothing of fakes/: fake:// exists once the simulated cell is wired in."""
    code = (
        "from drivers import DeviceConfigError, create_device\n"
        "try:\n    create_device('robot', 'fake://')\n"
        "except DeviceConfigError as e:\n    print(e)\n"
        "from fakes.wiring import register_fakes\nregister_fakes()\n"
        "from fakes.world import StaticWorld\n"
        "print(type(create_device('robot', 'fake://', world=StaticWorld())).__name__)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.splitlines()
    assert "no robot backend for fake:// (the simulated cell's: not wired in here)" in first
    assert second == "FakeRobot"
