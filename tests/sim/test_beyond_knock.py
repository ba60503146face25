"""A change beyond a knock on the simulated line (issue 41): the service holds the cell in
FAULT for maintenance within 3 windows of the event, applies no correction, keeps every body
since the event in an open suspect interval and names what moved (checked against the
simulated cell's truth) and the procedure that fits. Seeds and event times not tuned on."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.config import load_cell
from app.line.statedir import StateDir
from app.line.states import AlarmCode, State
from app.line.store import Store
from app.sim.line_run import SimulatedLineRun

pytestmark = pytest.mark.slow

AT_S = 660.0  # inside the 12th period of 60 s: its window is the first after the event


def _run(tmp_path: Path, kind: str, seed: int, axis: int = 3, sphere: str = "") -> dict[str, Any]:
    cfg = load_cell(None)
    simline = dataclasses.replace(
        cfg.simline,
        maintenance_at_s=AT_S,
        maintenance_kind=kind,
        maintenance_axis=axis,
        maintenance_sphere=sphere,
    )
    cfg = dataclasses.replace(cfg, simline=simline)
    with SimulatedLineRun(cfg, tmp_path / "state", seed=seed, geometric=True) as run:
        events: list[dict[str, Any]] = []
        summary = run.run_windows(30, on_event=events.append)
        states = [e["to"] for e in events if e["event"] == "state"]
        out = {
            "summary": summary,
            "truth": run.cell.maintenance_truth(),
            "state": states[-1] if states else None,
            "fault_bit": run.line.plc.received.fault,
        }
    store = Store.read_only(StateDir(tmp_path / "state").db)  # the service stopped: its record
    try:
        return out | {
            "alarms": store.active_alarms(code=AlarmCode.MAINTENANCE),
            "suspects": store.suspects(),
            "windows": store.windows(),
            "applied": store.applied(),
        }
    finally:
        store.close()


def _event_window(out: dict[str, Any]) -> int:
    """The first window that opened after the event (the line's own windows, 1-based)."""
    recs = out["summary"].records
    return next(r.window for r in recs if r.t_open_h * 3600.0 >= AT_S)


@pytest.mark.parametrize(
    ("kind", "seed", "axis", "sphere"),
    [
        ("sensor", 5, 3, ""),
        ("axis", 6, 2, ""),
        ("axis", 7, 5, ""),
        ("fixture", 8, 3, ""),
        ("fixture", 10, 3, "P3"),  # one sphere replaced: no kinematic group explains it
    ],
)
def test_a_change_beyond_a_knock_holds_the_cell_for_its_procedure(
    tmp_path: Path, kind: str, seed: int, axis: int, sphere: str
) -> None:
    out = _run(tmp_path, kind, seed, axis, sphere)
    s, truth = out["summary"], out["truth"]
    k = _event_window(out)
    assert s.maintenance, "the service did not hold for maintenance"
    # held within 3 windows; one sphere moved alone is seen when it is measured (a slot a
    # window, the spheres in turn: within 4), and until then the bodies are measured with a
    # measuring chain that did not change (the spheres are its reference, not part of it);
    # the jump test names it once two more spheres were measured where they stood (one
    # measurement fits the chain's groups as well as the sphere: 2 more windows, in its
    # suspect interval meanwhile; the drift charts' rule named it at once, on the measurements
    # before the flag)
    assert len(s.records) - k + 1 <= (6 if sphere else 3), (len(s.records), k)
    assert out["state"] == State.FAULT and out["fault_bit"]  # no body measured with it
    assert [a["version"] for a in out["applied"]] == [1]  # no correction applied
    text = out["alarms"][-1]["message"]
    # what moved, and the procedure that fits, against the truth
    if kind == "sensor":
        assert "sensor mount moved" in text and "rvis maintain sensor" in text, text
        # the shift and the tilt are confounded at views near the standoff; their effect is not
        found = re.search(r"([0-9.]+) mm at the measured spheres", text)
        assert found is not None, text
        mm = float(found.group(1))
        assert mm == pytest.approx(truth["mount_at_standoff_mm"], rel=0.2), (mm, truth)
    elif kind == "fixture" and sphere:
        found = re.search(rf"sphere {sphere} moved ([0-9.]+) mm on its own", text)
        assert found is not None and "rvis maintain fixture" in text, text
        true_mm = truth["spheres_moved_mm"][sphere]
        assert float(found.group(1)) == pytest.approx(true_mm, rel=0.1, abs=0.05), truth
    elif kind == "fixture":
        assert "part frame moved" in text and "rvis maintain fixture" in text, text
    elif "no sphere seen" not in text:  # a large zero may leave no sphere in view
        assert f"rvis maintain axis {axis}" in text, text
        deg = [float(v) for v in re.findall(r"([+-]?[0-9.]+) deg", text.split(" moved ")[1])]
        true_deg = truth["zero_change_deg"][axis - 1]
        assert abs(deg[0]) == pytest.approx(abs(true_deg), rel=0.1), (deg, truth)
    # every body clamped from the event on is in an open suspect interval (one sphere moved
    # alone: from its first measurement after the event; the windows before it measured with
    # the unchanged chain, within the U95 they stated)
    open_ = [x for x in out["suspects"] if x["t_end"] is None]
    assert len(open_) == 1
    t0 = open_[0]["t_start"]
    epoch = out["windows"][0]["t"] - s.records[0].t_open_h * 3600.0
    after = [w for w in out["windows"] if w["t"] - epoch >= AT_S]
    if sphere:
        unseen = [w for w in after if w["t"] < t0]
        assert len(unseen) <= 3
        for r in s.records:
            if r.t_open_h * 3600.0 >= AT_S and epoch + r.t_open_h * 3600.0 < t0:
                assert r.u95_mm is not None and r.rmse_mm <= r.u95_mm, r
        after = [w for w in after if w["t"] >= t0]
    assert after and all(w["t"] >= t0 for w in after)


def test_knocks_are_still_corrected_in_line_not_held(tmp_path: Path) -> None:
    """The bound is above a knock: the knock campaign's sensor knock is corrected in-line."""
    cfg = load_cell(None)
    simline = dataclasses.replace(cfg.simline, knock_at_s=AT_S, knock_kind="sensor")
    cfg = dataclasses.replace(cfg, simline=simline)
    with SimulatedLineRun(cfg, tmp_path / "state", seed=9, geometric=True) as run:
        s = run.run_windows(25)
        assert not s.maintenance and run.service.state != State.FAULT
        assert len(run.service.store.applied()) >= 2
        assert np.isfinite(s.true_rmse_final_mm) and s.true_rmse_final_mm < 0.2
