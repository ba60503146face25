"""A suspect interval's bodies computed again once (app/line/body_cycle.py): an interval whose
bodies may all precede the step (none measured after its first moved measurement) is handled
once, its counts stored, not again at every window."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from app.config.line import LineSettings
from app.inspect.plan import Feature, FeaturePlan
from app.inspect.values import StopNoise
from app.line.body_cycle import BodyCycle, BodySetup
from app.line.store import Store
from vision.sensor_model import default_sensor_model


def _row(store: Store, t: float, body_id: int) -> int:
    evaluation = {"t": t, "params_version": 1, "statement_u95_mm": 0.08, "reason": "measured",
                  "ok": 1, "n_nok": 0, "n_undecided": 0, "n_not_measured": 0}  # fmt: skip
    return store.add_body({"t": t, "body_id": body_id, "part": "P"}, evaluation, [], [])


def test_an_interval_with_nothing_to_compute_again_is_handled_once(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    measurement: dict[str, Any] = {
        "t": 150.0, "window": 1, "slot": 0, "target": "P1", "q_deg": [0.0] * 6,
        "c_sensor_mm": [0.0, 0.0, 130.0], "status": "ok", "reason": "", "quality": {},
        "params_version": 1, "residual_mm": 0.05, "next_position": 1,
    }  # fmt: skip
    store.add_measurement({**measurement, "t": 100.0})
    onset = store.add_measurement(measurement)
    _row(store, 120.0, 7)  # between the last good measurement (100) and the first moved (150)
    sid = store.open_suspect({"t_start": 100.0, "onset_id": onset, "params_version": 1})
    store.update_suspect(sid, t_end=200.0, end_reason="step", end_version=2)
    tols = {"position_tol_mm": (-0.5, 0.5), "size_tol_mm": (-0.2, 0.2)}
    z = np.zeros(3)
    feature = Feature("H1", "hole", z, np.array([0.0, 0.0, 1.0]), z, (8.0,), 0.8, tols)
    setup = BodySetup(FeaturePlan("P", "", (feature,)), SimpleNamespace(), default_sensor_model())
    watch = SimpleNamespace(clock=None, line=LineSettings(), plc=None)
    cycle = BodyCycle(setup, watch, None, store, StopNoise(0.07, 0.02))  # type: ignore[arg-type]

    def no_file(version: int) -> Path:
        raise AssertionError("no body to compute again: no parameters file read")

    assert cycle.reevaluate_pending(no_file, 0.08) == [
        {"id": sid, "bodies": 0, "decisions_changed": 0, "not_reevaluated": 1}
    ]
    assert cycle.reevaluate_pending(no_file, 0.08) == []  # not again at the next window
    (row,) = store.suspects()
    assert (row["reevaluated"], row["not_reevaluated"]) == (0, 1)
    store.close()
