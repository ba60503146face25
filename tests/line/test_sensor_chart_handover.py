"""The PS chart after a maintenance hand-over (app/line/service.py): the service started after a
procedure handed the cell back charts the measurements since the hand-over alone. A replaced
sensor has a PS of its own (the rendered line's new sensor: -18 um against the old one's +4);
charted against the old sensor's baseline it raised "PS shifted: the sensor changed" in its third
window after a hand-over that had calibrated it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from app.line.params_store import MAINTENANCE_SOURCE, ParamsStore, hand_over
from app.line.store import Store
from tests.line.helpers import make_line


def _row(k: int, ps_mm: float, t: float) -> dict[str, Any]:
    """A good measurement whose free sphere fit gives PS `ps_mm` (app.line.sensor_watch)."""
    return {
        "t": t + k,
        "window": k,
        "slot": 0,
        "target": "P1",
        "q_deg": [0.0] * 6,
        "c_sensor_mm": [0.0, 0.0, 130.0],
        "status": "ok",
        "quality": {"radius_free_mm": 15.0 + ps_mm / 2, "radius_dev_mm": ps_mm / 2},
        "params_version": 1,
        "next_position": 0,
    }


def test_after_a_hand_over_the_ps_chart_charts_the_new_sensor_against_its_own_baseline(
    tmp_path: Path,
) -> None:
    rng = np.random.default_rng(7)
    ln = make_line(tmp_path)
    svc = ln.service
    t0 = svc.clock.time()
    for k, ps in enumerate(rng.normal(0.004, 0.001, 120)):  # the sensor as it was
        svc.store.add_measurement(_row(k, float(ps), t0))
    svc.save_state()
    ln.close()
    # a maintenance procedure hands the cell back (a new sensor): its version in force
    params, store = ParamsStore(tmp_path), Store(tmp_path / "rvis.db")
    doc = dict(params.current_document() or {}) | {"source": MAINTENANCE_SOURCE}
    version = hand_over(params, store, doc, t0 + 200.0)
    store.close()
    ln = make_line(tmp_path)
    try:
        svc = ln.service
        assert svc.version == version and svc.decision.maintained_from_id == 121
        watch = svc.sensor_watch
        assert watch.n == 0  # nothing of the sensor before the hand-over charted
        new_sensor = rng.normal(-0.018, 0.001, 150)
        assert not any(watch.update(float(v)) for v in new_sensor)
        assert watch.mean_mm < -0.015  # its own baseline, learned from its own values
    finally:
        ln.close()
