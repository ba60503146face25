"""The in-line chart of the sensor's probing error size PS (app/line/sensor_watch.py): on the
rendered simulated line, a sensor calibration whose scale is 0.1 % off (the focal lengths)
raises the `sensor` alarm, which says the sensor changed and not the robot; the true calibration
raises none. And the chart's two signals on known sequences, and its restart."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from app.config import CellConfig
from app.line.sensor_watch import SensorWatch
from app.sim.cell import make_cell, true_sensor_model
from app.sim.line_run import SimulatedLineRun
from vision.sensor_model import SensorModel

WAIT_S = 60.0


def _short_line(cfg: CellConfig) -> CellConfig:
    """The rendered line with 12-frame sweeps, two slots per 8 s clamp cycle at time x2."""
    simline = dataclasses.replace(
        cfg.simline, scale=2.0, period_s=8.0, window_s=7.0, warmup_k=0.0, n_validation=4
    )
    sweep = dataclasses.replace(cfg.sweep, n_frames=12, grab_timeout_s=0.5)
    return dataclasses.replace(cfg, simline=simline, sweep=sweep)


def _scaled(model: SensorModel, focal_scale: float) -> SensorModel:
    K = model.camera.K.copy()
    K[0, 0] *= focal_scale
    K[1, 1] *= focal_scale
    return dataclasses.replace(model, camera=dataclasses.replace(model.camera, K=K))


def _measure(cfg: CellConfig, tmp: Path, focal_scale: float, n: int) -> tuple[list[str], int]:
    """The `sensor` alarms' texts within the first n measurements, and how many were ok."""
    cfg = _short_line(cfg)
    model = _scaled(true_sensor_model(make_cell(cfg, seed=5).sensor), focal_scale)
    alarms: list[str] = []
    ok = 0
    deadline = time.monotonic() + WAIT_S
    with SimulatedLineRun(cfg, tmp / "state", seed=5, sensor_model=model) as run:
        run.start_service()
        seen: list[str] = []
        stop = lambda e: len(seen) >= n or time.monotonic() > deadline  # noqa: E731
        for e in run.events_until(stop, WAIT_S):
            if e["event"] == "measurement":
                seen.append(e["status"])
                ok += e["status"] == "ok"
            elif e["event"] == "alarm" and e["code"] == "sensor":
                alarms.append(e["message"])
    return alarms, ok


def test_a_sensor_scale_error_raises_the_sensor_alarm(cfg: CellConfig, tmp_path: Path) -> None:
    alarms, ok = _measure(cfg, tmp_path, 1.001, 5)
    assert ok >= 3
    (text,) = alarms
    assert "not the robot" in text and "beyond its acceptance" in text


def test_the_true_sensor_calibration_raises_none(cfg: CellConfig, tmp_path: Path) -> None:
    alarms, ok = _measure(cfg, tmp_path, 1.0, 5)
    assert ok == 5 and alarms == []


def test_the_chart_signals_a_shift_within_the_limits_once() -> None:
    rng = np.random.default_rng(0)
    watch = SensorWatch(limit_mm=0.015, baseline_n=16)
    quiet = [watch.update(v) for v in rng.normal(0.001, 0.002, 40)]
    assert not any(quiet)
    shifted = [watch.update(v) for v in rng.normal(0.009, 0.002, 10)]  # +8 um: 4 sigma
    signals = [s for s in shifted if s]
    assert len(signals) == 1 and "shifted from its baseline" in signals[0]


def test_the_chart_is_rebuilt_at_a_restart_without_signalling_again() -> None:
    bad = [{"radius_free_mm": 14.99, "radius_dev_mm": -0.01}] * 10  # PS -20 um
    watch = SensorWatch(limit_mm=0.015)
    assert any(watch.update(SensorWatch.ps_of(q) or 0.0) for q in bad)
    again = SensorWatch(limit_mm=0.015)
    again.replay(bad)
    assert again.update(-0.02) is None  # raised before the restart, not twice
    assert SensorWatch.ps_of({"path": "geometric"}) is None
