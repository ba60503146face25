"""`rvis sensor measure` and `rvis sensor calibrate` on recorded (rendered) data on disk."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.commands.cli import main
from fakes.render import default_sweep_commands, render_sphere_sweep
from fakes.render_noise import NoiseSettings
from fakes.render_sensor import TrueSensor
from fakes.render_targets import render_calibration_set
from vision.sensor_model import load_sensor_model

CENTRE = np.array([1.0, -0.5, 129.0])


def write_sweep(folder: Path, frames: np.ndarray, commands: np.ndarray) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rows = ["frame,command_v"]
    for i, (frame, cmd) in enumerate(zip(frames, commands, strict=True)):
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), frame)
        rows.append(f"frame_{i:03d}.png,{float(cmd)!r}")
    (folder / "commands.csv").write_text("\n".join(rows) + "\n")


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory: pytest.TempPathFactory, true_sensor: TrueSensor) -> Path:
    folder = tmp_path_factory.mktemp("sweep")
    frames, cmds, _ = render_sphere_sweep(
        CENTRE,
        15.0,
        true_sensor,
        np.random.default_rng(4),
        commands_v=default_sweep_commands(20, 3.2),
        noise=NoiseSettings(bits=12),
    )
    write_sweep(folder, frames, cmds)
    return folder


def test_measure_prints_the_centre(sweep_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensor", "measure", str(sweep_dir), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert np.abs(np.array(out["c_sensor_mm"]) - CENTRE).max() < 0.005
    assert main(["sensor", "measure", str(sweep_dir), "--mode", "precise"]) == 0
    words = capsys.readouterr().out.split()
    assert words[0] == "centre_sensor_mm"
    assert np.abs(np.array(words[1:4], float) - CENTRE).max() < 0.005


def _copy(src: Path, dst: Path) -> Path:
    dst.mkdir()
    for p in src.iterdir():
        (dst / p.name).write_bytes(p.read_bytes())
    return dst


@pytest.mark.parametrize(
    ("edit", "expect"),
    [
        (lambda d: (d / "commands.csv").unlink(), "commands.csv: sweep file not found"),
        (lambda d: (d / "commands.csv").write_text("frame,volts\n"), "commands.csv:1: header"),
        (
            lambda d: (d / "commands.csv").write_text("frame,command_v\nframe_000.png,x\n"),
            "commands.csv:2: field 'command_v': not a number",
        ),
        (
            lambda d: (d / "frame_000.png").write_bytes(b"not a png"),
            "frame_000.png: not a readable image",
        ),
        (lambda d: (d / "frame_001.png").unlink(), "frame_001.png: image file not found"),
    ],
)
def test_bad_sweeps_give_one_line_and_exit_2(
    sweep_dir: Path, tmp_path: Path, edit: object, expect: str, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _copy(sweep_dir, tmp_path / "bad")
    edit(bad)  # type: ignore[operator]
    assert main(["sensor", "measure", str(bad)]) == 2
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1 and "Traceback" not in err


def test_bad_sensor_file_exit_2(
    sweep_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "sensor.toml"
    bad.write_text('format = "rvis-sensor/1"\n[camera]\n[laser]\n')
    assert main(["sensor", "measure", str(sweep_dir), "--sensor", str(bad)]) == 2
    assert "field 'camera.fx_px'" in capsys.readouterr().err


def test_rejected_measurement_exit_3(
    sweep_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dark = _copy(sweep_dir, tmp_path / "dark")
    for png in dark.glob("*.png"):
        cv2.imwrite(str(png), np.full((966, 1296), 20, np.uint16))
    assert main(["sensor", "measure", str(dark)]) == 3
    assert "measurement rejected: no valid stripe" in capsys.readouterr().err


def test_calibrate_writes_a_usable_sensor_file(
    tmp_path: Path, true_sensor: TrueSensor, sweep_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cset = render_calibration_set(
        true_sensor, np.random.default_rng(8), n_chessboards=10, n_targets=3, n_commands=7
    )
    root = tmp_path / "calib"
    (root / "chessboards").mkdir(parents=True)
    for i, img in enumerate(cset.chessboards):
        cv2.imwrite(str(root / "chessboards" / f"cb_{i:02d}.png"), np.asarray(img, np.uint8))
    for k, (board, frames) in enumerate(cset.targets):
        pose = root / "targets" / f"pose_{k}"
        write_sweep(pose, frames, cset.commands_v)
        cv2.imwrite(str(pose / "board.png"), np.asarray(board, np.uint8))
    out = tmp_path / "sensor.toml"
    assert main(["sensor", "calibrate", str(root), "--out", str(out)]) == 0
    model = load_sensor_model(out)
    assert abs(model.camera.K[0, 0] / true_sensor.fx_px - 1) < 3e-3
    assert main(["sensor", "measure", str(sweep_dir), "--sensor", str(out), "--json"]) == 0
    centre = np.array(json.loads(capsys.readouterr().out.splitlines()[-1])["c_sensor_mm"])
    assert np.linalg.norm(centre - CENTRE) < 0.2
    # missing chessboards: exit 2 with the reason
    for png in (root / "chessboards").glob("*.png"):
        png.unlink()
    assert main(["sensor", "calibrate", str(root), "--out", str(out)]) == 2
    assert "calibration failed" in capsys.readouterr().err
