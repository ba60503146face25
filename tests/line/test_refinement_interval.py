"""A refinement after an episode's interval closed (app.line.jumps): the group tested again on the
measurements since its correction was still off, so the parameters of the correction were still
the suspect ones. When the refinement comes into force the interval ends there, with it as its
end version, and its bodies are to be computed again with it; a batch recalibration in force at
that point does not move the end."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from app.line.events import EventBus
from app.line.jumps import JumpWatch
from app.line.store import Store
from fakes.clock import VirtualClock


def _watch(tmp_path: Path) -> tuple[JumpWatch, Any]:
    store = Store(tmp_path / "rvis.db")
    clock = VirtualClock(start_epoch=1000.0)
    svc = SimpleNamespace(store=store, clock=clock, version=2, bus=EventBus(store, clock))
    watch = JumpWatch(svc)
    watch.restart = lambda: None  # type: ignore[method-assign]  # (the estimator's tests)
    sid = store.open_suspect({"t_start": 900.0, "onset_id": 5, "params_version": 1})
    store.update_suspect(
        sid, t_end=950.0, end_reason="step", end_version=2, text="step: sensor mount",
        reevaluated=3, decisions_changed=1, not_reevaluated=0,
    )  # fmt: skip
    svc.episode = {
        "onset_id": 5, "suspect_id": sid, "group": "sensor", "corrected_version": 2,
        "closed": True, "watch_left": 10, "refined": 1, "refining": True,
    }  # fmt: skip
    return watch, svc


def test_a_refinement_after_the_interval_closed_ends_the_interval_there(tmp_path: Path) -> None:
    watch, svc = _watch(tmp_path)
    svc.clock.advance(120.0)
    svc.version = 3
    watch.in_force("step")
    (row,) = svc.store.suspects()
    assert row["t_end"] == pytest.approx(1120.0) and row["end_version"] == 3
    assert row["text"].endswith("refined on version 3 (the group still off)")
    # computed again with the refinement (reevaluate_pending takes intervals with none)
    assert row["reevaluated"] is None and row["decisions_changed"] is None
    assert "refining" not in svc.episode
    svc.version = 4
    watch.in_force("step")  # no refinement asked for: the end stays
    assert svc.store.suspects()[0]["end_version"] == 3
    svc.store.close()


def test_a_batch_recalibration_in_force_does_not_move_the_end(tmp_path: Path) -> None:
    watch, svc = _watch(tmp_path)
    svc.clock.advance(60.0)
    svc.version = 3
    watch.in_force("batch")
    (row,) = svc.store.suspects()
    assert row["t_end"] == 950.0 and row["end_version"] == 2 and row["reevaluated"] == 3
    svc.store.close()
