"""The commissioning report says what it means (issue 30 item 9): shares as per cent with
their counts, limits with their units, one range check instead of two of the same name,
figures whole (no "..."), the simulated line's truth marked as such, and a step that ran
again said so, with why (the journal keeps each step's earlier runs)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from app.commission.checks import Check, at_most, count_at_least, share_at_most, within
from app.commission.journal import PASSED, Journal, StepRecord
from app.commission.report import markdown, to_json

SETUP = {"cell": "cell.toml", "sim": True}


def _finish(journal: Journal, name: str, *checks: Check, **results: Any) -> None:
    started = "2026-11-25T06:00:00+00:00"
    journal.finish(StepRecord(name, PASSED, started, 1.5, checks, results, ()))


def test_the_report_says_shares_units_ranges_truth_and_runs(tmp_path: Path) -> None:
    journal = Journal(tmp_path, SETUP)
    journal.start("devices", "2026-11-25T05:00:00+00:00")
    _finish(journal, "devices")
    journal.start("stripe", "2026-11-25T05:10:00+00:00")  # then the process is killed
    journal = Journal(tmp_path, SETUP)  # the next run reads the journal
    assert "Started 2026-11-25T05:10:00+00:00; interrupted" in markdown(journal)
    journal.start("stripe", "2026-11-25T05:20:00+00:00")
    exposures = [{"exposure_us": e, "rows": 600 + e // 100, "peak_fraction": 0.07} for e in
                 (2500, 5000, 10000, 20000, 40000, 80000)]  # fmt: skip
    _finish(
        journal,
        "stripe",
        within("stripe peak, of full scale", 25.49, 15.0, 90.0, "%"),
        at_most("stripe width (RMS)", 1.86, 3.0, "px"),
        exposures=exposures,
    )
    journal.start("sensor", "2026-11-25T05:30:00+00:00")
    journal.finish(
        StepRecord(
            "sensor",
            "failed",
            "2026-11-25T05:30:00+00:00",
            2.0,
            (at_most("laser plane RMS", 0.2, 0.05, "mm"),),
            {},
            (),
        )
    )
    journal.start("sensor", "2026-11-25T05:40:00+00:00")
    _finish(
        journal,
        "sensor",
        share_at_most("views rejected by vision", 1, 24, 0.1),
        count_at_least("positions measured", 19, 20, 19.0),
        truth={"fx_error_px": -1.58, "cy_error_px": -2.69},
        true_rmse_mm=0.110984,
        spheres={"P1": {"x_mm": [245.7, -3147.1, 410.6], "rms_mm": 0.0152}},
    )
    md = markdown(journal)
    assert "| views rejected by vision (1 of 24) | 4.167 % | <= 10 % | yes |" in md
    assert "| positions measured | 19 of 20 | >= 19 of 20 | yes |" in md
    assert "| stripe peak, of full scale | 25.49 % | 15-90 % | yes |" in md
    assert "| stripe width (RMS) | 1.86 px | <= 3 px | yes |" in md
    assert md.count("stripe peak") == 1 and "peak / full scale" not in md
    assert " ..." not in md and "| 80000 | 1400 | 0.07 |" in md  # every exposure, a table
    assert "| P1 | 245.7, -3147.1, 410.6 | 0.0152 |" in md
    assert "- truth (simulation only: the simulated cell's truth, unknown on a real cell):" in md
    assert "- true_rmse_mm (simulation only: the simulated cell's truth" in md
    assert "Run 2 times: interrupted (started 2026-11-25T05:10:00+00:00), then passed." in md
    assert (
        "Run 2 times: failed (started 2026-11-25T05:30:00+00:00; failed laser plane RMS),"
        " then passed." in md
    )
    assert "| 3 | sensor | passed | 2/2 | 1.5 | 2 |" in md
    steps = {s["name"]: s for s in to_json(journal)["steps"]}
    assert [e["status"] for e in steps["stripe"]["earlier"]] == ["interrupted"]
    json.dumps(to_json(journal))  # the JSON report holds the same


def test_a_step_the_engineer_stopped_leaves_the_journal_as_it_was(tmp_path: Path) -> None:
    journal = Journal(tmp_path, SETUP)
    journal.start("devices", "2026-11-25T05:00:00+00:00")
    journal.abandon("devices")
    assert Journal(tmp_path, SETUP).steps == {}
    journal.start("devices", "2026-11-25T05:01:00+00:00")
    _finish(journal, "devices")
    journal.start("devices", "2026-11-25T05:02:00+00:00")  # (not in a sequence: a test of it)
    journal.abandon("devices")
    again = Journal(tmp_path, SETUP).steps["devices"]
    assert again.status == PASSED and again.earlier == ()
