"""`rvis sensor verify` on a commissioned state directory of the simulated line: the sensor
calibration in use measured at 9 positions across the measuring volume through rendered sweeps;
a calibration whose scale is 0.1 % off fails its acceptance (exit 3, PS named: SD's reference is
the robot's motion, whose repeatability, RP 0.07 mm, widens SD's limit by about 0.1 mm, more than
the scale error's 0.03 mm, and decides SD's verdict for the true sensor and the scaled one
alike), and a directory with nothing commissioned is a one-line input error."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.config import load_cell
from app.formats.params import plain_document
from app.line.params_store import ParamsStore
from app.line.statedir import StateDir
from app.sim.cell import make_cell, scaled_sensor_model, true_sensor_model
from app.sim.cold_calibration import commissioning
from tests.groups import GIGE_CAMERA
from vision.sensor_model import save_sensor_model

pytestmark = GIGE_CAMERA


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A state directory as commissioning leaves it, for what verify reads: the parameters in
    force (a calibration of the simulated cell) and the sensor calibration (the true one)."""
    state = tmp_path_factory.mktemp("verify") / "state"
    cfg = load_cell(None)
    x = commissioning(cfg, 0).x
    ParamsStore(state).apply(plain_document(cfg.identification_model(), x, "commissioning"))
    save_sensor_model(true_sensor_model(make_cell(cfg, seed=0).sensor), StateDir(state).sensor)
    return state


def test_a_sensor_with_a_scale_error_fails_its_acceptance(
    commissioned: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    true = true_sensor_model(make_cell(load_cell(None), seed=0).sensor)
    scaled = scaled_sensor_model(true, 1.001)
    save_sensor_model(scaled, tmp_path / "scaled.toml")
    capsys.readouterr()
    argv = ["sensor", "verify", "--sim", "--yes", "--state-dir", str(commissioned), "--json"]
    main(argv)  # the true sensor, at the same views and the robot's same stops
    exact = json.loads(capsys.readouterr().out)
    assert main([*argv, "--sensor", str(tmp_path / "scaled.toml")]) == 3
    doc = json.loads(capsys.readouterr().out)
    failed = [c["name"] for c in doc["checks"] if not c["ok"]]
    assert failed[0].startswith("probing error size |PS|, the largest of 9")
    assert doc["results"]["ps_mm"] < -0.015 < 0.015 > abs(exact["results"]["ps_mm"])
    # SD does not see the 0.1 % (about 0.03 mm at the volume's spacings): the robot's stops
    # decide its verdict, the true sensor's and the scaled one's alike. On this cell they put
    # even the true sensor over the widened limit (SD 0.138 mm against 0.119): a perfect
    # sensor fails SD at 2-4 % of the robot's stops (docs/commissioning.md, step 8), the open
    # question of an SD reference no stop error enters
    sd_exact, sd_scaled = exact["results"]["sd_mm"], doc["results"]["sd_mm"]
    assert abs(sd_scaled - sd_exact) < 0.03
    exact_failed = [c["name"].split(",")[0] for c in exact["checks"] if not c["ok"]]
    # anything else failed for the true sensor too (its worst pair may be another)
    assert [name.split(",")[0] for name in failed[1:]] == exact_failed
    # SD stated with the robot's share of it, the limit widened by that share
    results = doc["results"]
    assert results["robot_repeatability_mm"] == 0.07
    assert 0.05 < results["sd_robot_mm"] < 0.2
    (sd,) = (c for c in doc["checks"] if c["name"].startswith("sphere-spacing error |SD|"))
    share = results["sd_robot_mm"]
    assert sd["limit"] == f"<= {0.015 + share:.4f} mm (0.0150 + the robot's share {share:.4f})"
    # the worst pair named, every pair's SD and every position's PF and PS in the results; PF
    # leaves out at most VDI/VDE 2634-2's 0.3 % of a sweep's points
    (a, b) = max(results["pairs"], key=lambda p: abs(p["sd_mm"]))["pair"].split(" - ")
    assert (
        sd["name"].endswith(f"the largest of 36 pairs ({a} - {b})") and len(results["pairs"]) == 36
    )
    positions = results["positions"]
    assert [p["position"] for p in positions][:3] == ["centre", "left", "right"]
    assert all(0 < p["pf_left_out"] <= 0.003 * p["points"] for p in positions)
    assert max(p["pf_mm"] for p in positions) == results["pf_mm"]
    assert (StateDir(commissioned).root / "verify" / "acceptance.csv").is_file()


def test_nothing_commissioned_is_an_input_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sensor", "verify", "--sim", "--yes", "--state-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "sensor.toml" in err and "commission the cell first" in err
    assert len(err.splitlines()) == 1


def test_a_camera_lost_in_the_middle_fails_the_acceptance_with_the_reason(
    commissioned: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A device error in the middle of `rvis sensor verify` (the camera's frames stop coming)
    is the commissioning step's failed "devices" check, exit 3 with the reason: no traceback."""
    from app.line.measure import SweepSensor
    from drivers.errors import DeviceTimeout

    def no_frame(self: SweepSensor) -> Any:
        raise DeviceTimeout("aravis://127.0.0.1: no frame within 1 s")

    monkeypatch.setattr(SweepSensor, "grab_sweep", no_frame)
    argv = ["sensor", "verify", "--sim", "--yes", "--state-dir", str(commissioned), "--json"]
    assert main(argv) == 3
    doc = json.loads(capsys.readouterr().out)
    (failed,) = (c for c in doc["checks"] if not c["ok"])
    assert failed["name"] == "devices" and failed["value"].startswith("DeviceTimeout: aravis://")
