"""`rvis devices sim`'s cell file and folder (app/sim/line_devices.py), without starting the
devices: the cell file names the URLs given, states the PLC's window in wall seconds and the
seed, and reads back to the same values; a folder whose cell file another command wrote is
refused with one line naming it."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.commands.cli import main
from app.config import load_cell
from app.config.write import dumps_cell
from app.errors import InputError
from app.sim.line_devices import MARK, DevicesDir, check_folder, devices_cell

URLS = {
    "robot": "rmi://127.0.0.1:40001",
    "camera": "aravis://127.0.0.1",
    "galvo": "scpi+serial:///tmp/sim/galvo",
    "tracker": "tracker+tcp://127.0.0.1:40002",
    "plc": "plc+modbus://127.0.0.1:40003",
}


def test_the_cell_file_names_the_devices_the_window_in_wall_seconds_and_the_seed(
    tmp_path: Path,
) -> None:
    base = tmp_path / "base.toml"
    base.write_text("[simline]\nperiod_s = 30.0\nwindow_s = 12.0\n", encoding="utf-8")
    cfg = devices_cell(load_cell(base), URLS, seed=9, scale=4.0)
    assert cfg.devices.urls() == URLS
    assert cfg.line.window_s == 3.0  # 12 sim s at 4 sim s per real s
    assert cfg.simulation.seed == 9
    assert cfg.line.plc_temperature and cfg.line.plc_body_id == "u32"
    path = tmp_path / "cell.toml"
    path.write_text(dumps_cell(cfg, f"{MARK} (seed 9)"), encoding="utf-8")
    again = load_cell(path)
    assert again.devices.urls() == URLS and again.line.window_s == 3.0
    assert again.simulation.seed == 9 and again.simline.period_s == 30.0
    check_folder(DevicesDir(tmp_path))  # its own cell file: written again at the next start


def test_a_folder_with_another_cell_plan_or_sensor_file_is_refused(tmp_path: Path) -> None:
    (tmp_path / "cell.toml").write_text("[simline]\nscale = 2.0\n", encoding="utf-8")
    with pytest.raises(InputError, match="not written by `rvis devices sim`") as info:
        check_folder(DevicesDir(tmp_path))
    assert info.value.file == str(tmp_path / "cell.toml")
    (tmp_path / "cell.toml").unlink()
    (tmp_path / "sensor.toml").write_text("", encoding="utf-8")  # a sensor calibration
    with pytest.raises(InputError, match="no cell file of `rvis devices sim`") as info:
        check_folder(DevicesDir(tmp_path))
    assert info.value.file == str(tmp_path / "sensor.toml")


def test_the_command_refuses_a_commissioned_folder_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "cell.toml").write_text("", encoding="utf-8")
    assert main(["devices", "sim", "--dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"rvis devices: error: {tmp_path / 'cell.toml'}: a cell file not")
    assert len(err.strip().splitlines()) == 1
    assert main(["devices", "sim", "--dir", str(tmp_path / "new"), "--scale", "0"]) == 2
    assert "field '--scale': must be > 0" in capsys.readouterr().err


def test_a_file_where_the_galvo_link_goes_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The galvo's link replaces a link (one a killed devices process left), never a file."""
    (tmp_path / "galvo").write_text("a person's notes", encoding="utf-8")
    assert main(["devices", "sim", "--dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"rvis devices: error: {tmp_path / 'galvo'}: not the galvo's link of `rvis devices sim`"
        " (a file in its place): move it away"
    ]
    assert (tmp_path / "galvo").read_text(encoding="utf-8") == "a person's notes"
