"""The cell temperature through the line: the simulated line's PLC peer publishes the cell's
true temperature in its temperature word, the service reads it over Modbus with every poll,
stores it with every measurement and, with the compliant model, evaluates the thermal term at
it (residuals, recalibration, the sequential estimator)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from app.config import CellConfig
from app.sim.line_run import SimulatedLineRun
from calib.compliance import CompliantModel


def test_measurements_carry_the_plc_temperature_and_the_compliant_model_uses_it(
    cfg: CellConfig, tmp_path: Path
) -> None:
    fast = dataclasses.replace(
        cfg,
        calibration=dataclasses.replace(cfg.calibration, model="compliant"),
        line=dataclasses.replace(cfg.line, slots_per_window=2),
        service=dataclasses.replace(cfg.service, rolling_size=24),
    )
    with SimulatedLineRun(fast, tmp_path / "state", seed=5, geometric=True) as run:
        assert isinstance(run.service.model, CompliantModel)
        run.run_windows(20)  # 40 measurements: a recalibration on 24 + 4 held out
        svc = run.service
        rows = svc.store.measurements()
        truth_now = run.line.truth.temp_c()
        assert svc.cell_temp_c is not None and abs(svc.cell_temp_c - truth_now) < 0.2
        temps = np.array([r["temp_c"] for r in rows], dtype=float)
        t_s = np.array([r["t"] for r in rows]) - run.line.clock.time() + run.line.clock.monotonic()
        truth = np.array([run.line.truth.temp_c(t) for t in t_s])
        assert np.all(np.abs(temps - truth) < 0.05)  # 0.01 degC words, a poll apart
        assert temps[-1] > temps[0]  # the warm-up, seen by the service
        # the residual the service stored is the compliant model's at that temperature
        r = rows[0]
        assert r["params_version"] == 1  # the commissioning parameters
        q, c = np.array([r["q_deg"]]), np.array([r["c_sensor_mm"]])
        p = svc.model.points_part(run.x_commissioning, q, c, temp_c=np.array([r["temp_c"]]))[0]
        e = float(np.linalg.norm(p - fast.spheres_part_mm[r["target"]]))
        assert abs(e - r["residual_mm"]) < 1e-9
        p_cold = svc.model.points_part(run.x_commissioning, q, c, temp_c=np.array([0.0]))[0]
        assert np.linalg.norm(p_cold - p) > 1e-3  # the thermal term is not ignored
        cals = svc.store.calibrations()
        assert cals and cals[0]["document"]["model"]["kind"] == "compliant"


def _temperature_alarms(run: SimulatedLineRun) -> list[dict[str, Any]]:
    return [a for a in run.service.store.alarms() if a["code"] == "temperature"]


def test_a_plc_that_never_writes_the_word_is_no_temperature_with_an_alarm(
    cfg: CellConfig, tmp_path: Path
) -> None:
    """A PLC program that predates the temperature word leaves it at 0: with the compliant
    model's thermal term that would be a cell at 0 degC, 20 K off. The service reads no
    temperature, raises one `temperature` alarm, predicts as without a thermal term, and
    clears the alarm when a plausible value returns; the "no sensor" code alarms the same."""
    fast = dataclasses.replace(
        cfg,
        calibration=dataclasses.replace(cfg.calibration, model="compliant"),
    )
    with SimulatedLineRun(fast, tmp_path / "state", seed=5, geometric=True) as run:
        svc, plc = run.service, run.line.plc
        truth_temp = plc.temperature
        plc.temperature = lambda: 0.0  # the word a PLC program never writes: 0x0000
        run.run_windows(4)
        assert svc.cell_temp_c is None
        [alarm] = _temperature_alarms(run)  # raised once, not once per poll
        assert alarm["state"] == "raised" and alarm["priority"] == "medium"
        assert "0.00 degC" in alarm["message"] and "plc_temp_min_c" in alarm["message"]
        rows = svc.store.measurements()
        assert rows and all(r["temp_c"] is None for r in rows)
        model, x = svc.model, run.x_commissioning
        assert isinstance(model, CompliantModel)
        for r in rows[:2]:  # rigid-equivalent: the thermal term left out, never at 0 degC
            q, c = np.array([r["q_deg"]]), np.array([r["c_sensor_mm"]])
            target = fast.spheres_part_mm[r["target"]]
            p_none = model.points_part(x, q, c)[0]
            p_ref = model.points_part(x, q, c, temp_c=np.array([20.0]))[0]  # reference_temp_c
            p_zero = model.points_part(x, q, c, temp_c=np.array([0.0]))[0]
            assert np.linalg.norm(p_none - p_ref) < 1e-9
            assert abs(float(np.linalg.norm(p_none - target)) - r["residual_mm"]) < 1e-9
            assert np.linalg.norm(p_zero - p_none) > 1e-2  # what 0.00 degC would have cost
        plc.temperature = truth_temp  # the PLC program now writes the word
        run.run_windows(6)  # counted from the start
        assert svc.cell_temp_c is not None
        [alarm] = _temperature_alarms(run)
        assert alarm["state"] == "cleared"
        assert svc.store.measurements()[-1]["temp_c"] is not None
        plc.temperature = lambda: None  # the "no sensor" code, 0x8000
        run.run_windows(8)
        assert svc.cell_temp_c is None
        assert [a["state"] for a in _temperature_alarms(run)] == ["cleared", "raised"]
        assert "no sensor (0x8000)" in _temperature_alarms(run)[-1]["message"]
