"""The cell temperature through the line: the simulated line's PLC peer publishes the cell's
true temperature in its temperature word, the service reads it over Modbus with every poll,
stores it with every measurement and, with the compliant model, evaluates the thermal term at
it (residuals, recalibration, the sequential estimator)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from app.config import CellConfig
from app.sim.line_run import SimulatedLineRun
from calib.compliance import CompliantModel


def test_measurements_carry_the_plc_temperature_and_the_compliant_model_uses_it(
    cfg: CellConfig, tmp_path: Path
) -> None:
    fast = dataclasses.replace(
        cfg,
        simline=dataclasses.replace(cfg.simline, scale=150.0),
        calibration=dataclasses.replace(cfg.calibration, model="compliant"),
        line=dataclasses.replace(cfg.line, slots_per_window=2),
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
