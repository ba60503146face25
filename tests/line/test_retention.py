"""Retention (issue 19): events older than [service] events_keep_days are deleted between
windows, and the full documents of calibrations rejected more than rejected_keep_days ago are
dropped; the record (measurements, calibrations with their figures, alarms, the audit) is
kept."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from app.line.store import Store
from tests.line.helpers import make_line

DAY_S = 86400.0


def test_prune_events_deletes_only_the_old_ones_in_short_transactions(tmp_path: Path) -> None:
    store = Store(tmp_path / "rvis.db")
    for k in range(25):
        store.add_event(float(k), "old", {"k": k})
    store.add_event(100.0, "new", {})
    store.raise_alarm(1.0, "drift", "kept")
    assert store.prune_events(before_t=50.0, batch=4) == 25
    assert [e["kind"] for e in store.events()] == ["new"]
    assert len(store.alarms()) == 1
    store.close()


def _calibration(store: Store, t: float, status: str) -> int:
    return store.add_calibration(
        {
            "t": t,
            "status": status,
            "n_measurements": 24,
            "gates": ["g"],
            "reason": "r",
            "rms_mm": 0.03,
            "document": {"parameters": [], "correlation": [[1.0]]},
        }
    )


@pytest.mark.parametrize("keep_days", [90.0, 0.0])
def test_the_service_deletes_events_past_their_retention(tmp_path: Path, keep_days: float) -> None:
    ln = make_line(tmp_path)
    ops = replace(
        ln.service.settings.ops, events_keep_days=keep_days, rejected_keep_days=keep_days / 3
    )
    ln.service.settings = replace(ln.service.settings, ops=ops)
    now = ln.clock.time()
    store = ln.service.store
    old = [store.add_event(now - 100 * DAY_S, "window", {"n": k}) for k in range(3)]
    recent = store.add_event(now - 10 * DAY_S, "window", {"n": 3})
    old_rejected = _calibration(store, now - 40 * DAY_S, "rejected")
    new_rejected = _calibration(store, now - 20 * DAY_S, "rejected")
    old_applied = _calibration(store, now - 40 * DAY_S, "applied")
    try:
        ln.start()
        ln.windows(1)
        ids = {e["id"] for e in store.events()}
        docs = {i: store.calibration(i) for i in (old_rejected, new_rejected, old_applied)}
    finally:
        ln.close()
    assert recent in ids
    assert set(old).isdisjoint(ids) if keep_days else set(old) <= ids
    assert all(c is not None and c["rms_mm"] == 0.03 for c in docs.values())  # the record
    kept = {i for i, c in docs.items() if c is not None and c["document"] is not None}
    assert kept == ({new_rejected, old_applied} if keep_days else set(docs))
