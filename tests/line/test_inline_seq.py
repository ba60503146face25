"""The sequential estimator as the service's recalibration (app/line/inline_seq.py), on
measurements of the simulated cell: the newest rows stay held out, candidates are gated
against the parameters in force on them, the covariance of an identification is taken from
its document, and a flagged step drops the stale held-out rows and waits for a full cycle."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.config import load_cell
from app.config.line import RecalibSettings
from app.formats.params import to_json
from app.line.inline_seq import InlineSequential, covariance_from
from app.sim.cell import make_cell
from calib.gate_limits import INLINE
from calib.identify import Measurements, identify
from tests.line.helpers import plan_for

SEED = 3
CELLS: dict[int, Any] = {}


def _rows(n_cycles: int) -> tuple[list[dict[str, Any]], Any]:
    """Measurement rows (as the service stores them) of the plan's 24 views, cycled."""
    cfg = load_cell(None)
    cell = CELLS.setdefault(SEED, make_cell(cfg, SEED))
    plan = plan_for(SEED)
    rows: list[dict[str, Any]] = []
    for _ in range(n_cycles):
        for slot, (tid, q) in enumerate((t, q) for t, qs in plan.items() for q in qs):
            c = cell.measure_point(q, cfg.spheres_part_mm[tid])
            rows.append(
                {
                    "id": len(rows) + 1,
                    "slot": slot,
                    "target": tid,
                    "q_deg": q.tolist(),
                    "c_sensor_mm": c.tolist(),
                }
            )
    return rows, cfg


def _true_rms(cfg: Any, x: np.ndarray, rows: list[dict[str, Any]]) -> float:
    """True RMS error [mm] of the model with x at the rows' configurations: the noise-free
    centres the cell's truth puts in the sensor frame, mapped back to the part."""
    cell = CELLS[SEED]
    q = np.array([r["q_deg"] for r in rows])
    p = np.array([cfg.spheres_part_mm[r["target"]] for r in rows])
    c = np.array([cell.centre_in_sensor(qi[None], pi)[0] for qi, pi in zip(q, p, strict=True)])
    e = cfg.model().points_part(x, q, c) - p
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def test_held_out_lag_and_gated_candidates_that_improve_the_nominal() -> None:
    rows, cfg = _rows(3)
    model = cfg.model()
    settings = RecalibSettings(estimator="sequential", seq_apply_every=8, holdout_size=4)
    seq = InlineSequential(settings, INLINE, cfg.spheres_part_mm)
    seq.restart(model, model.nominal_x(), None)
    x_in_force = model.nominal_x()
    applied = 0
    for row in rows:
        seq.offer(row)
        if seq.due():
            cand = seq.candidate(model, x_in_force)
            held_out = [r["id"] for r in rows if r["id"] > row["id"] - 4]
            assert cand.last_id == row["id"] and len(seq.queue) == 4
            assert cand.first_id < held_out[0]  # trained on rows before the held-out ones
            if cand.passed:
                assert cand.holdout_rms_mm <= cand.current_holdout_rms_mm
                x_in_force = model.nominal_x()
                x_in_force[:] = [p["value"] for p in cand.document["parameters"]]
                applied += 1
    assert seq.est is not None and seq.est.n_accepted + seq.est.n_rejected == len(rows) - 4
    assert applied >= 3
    first_cycle = rows[:24]
    assert _true_rms(cfg, x_in_force, first_cycle) < 0.2 * _true_rms(
        cfg, model.nominal_x(), first_cycle
    )


def test_covariance_from_an_identification_document() -> None:
    rows, cfg = _rows(2)
    model = cfg.model()
    data = Measurements(
        np.array([r["q_deg"] for r in rows]),
        np.array([r["c_sensor_mm"] for r in rows]),
        np.array([cfg.spheres_part_mm[r["target"]] for r in rows]),
        tuple(r["target"] for r in rows),
    )
    result = identify(model, data)
    names, cov = covariance_from(to_json(model, result), model)
    assert names == list(result.active)
    assert np.allclose(np.sqrt(np.diag(cov)), result.std, rtol=1e-5)
    assert covariance_from(None, model)[0] == []
