"""The commissioning report says what it means (issue 30 item 9): shares as per cent with
their counts, limits with their units, one range check instead of two of the same name,
figures whole (no "..."), the simulated line's truth marked as such, and a step that ran
again said so, with why (the journal keeps each step's earlier runs); issue 40 item 5: ratios
stated as ratios (value, limit and the two figures at one precision), figures stated without a
limit in the checks table, millimetres to 0.1 um, PF, PS and SD saying what they are the largest
of and where."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from app.commission.acceptance import POSITIONS, figure_checks
from app.commission.checks import (
    MM,
    Check,
    at_most,
    count_at_least,
    ratio_at_least,
    ratio_at_most,
    share_at_most,
    stated,
    within,
)
from app.commission.journal import PASSED, Journal, StepRecord
from app.commission.report import check_line, check_row, markdown, to_json
from vision.acceptance import Acceptance, AcceptanceLimits

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
        spheres={"P1": {"x_mm": 245.7, "y_mm": -3147.1, "z_mm": 410.6, "rms_mm": 0.0152}},
    )
    md = markdown(journal)
    assert "| views rejected by vision (1 of 24) | 4.167 % | <= 10 % | yes |" in md
    assert "| positions measured | 19 of 20 | >= 19 of 20 | yes |" in md
    assert "| stripe peak, of full scale | 25.49 % | 15-90 % | yes |" in md
    assert "| stripe width (RMS) | 1.86 px | <= 3 px | yes |" in md
    assert md.count("stripe peak") == 1 and "peak / full scale" not in md
    assert " ..." not in md and "| 80000 | 1400 | 0.07 |" in md  # every exposure, a table
    assert "| name | x_mm | y_mm | z_mm | rms_mm |" in md  # millimetres to 0.1 um
    assert "| P1 | 245.7000 | -3147.1000 | 410.6000 | 0.0152 |" in md
    assert "- true_rmse_mm (simulation only: the simulated cell's truth, unknown on a real cell)" \
        ": 0.1110" in md  # fmt: skip
    assert "- truth (simulation only: the simulated cell's truth, unknown on a real cell):" in md
    assert "- true_rmse_mm (simulation only: the simulated cell's truth" in md
    assert "Run 2 times: interrupted (started 2026-11-25T05:10:00+00:00), then passed." in md
    assert (
        "Run 2 times: failed (started 2026-11-25T05:30:00+00:00; failed laser plane RMS),"
        " then passed." in md
    )
    assert "| 3 | sensor | passed | 2/2 | 1.5 | 2 |" in md
    assert "Run again: stripe (after 1 interrupted run), sensor (after 1 failed run)." in md
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


def test_ratios_say_what_they_are_of_at_one_precision() -> None:
    """A ratio is stated as one: its value and limit, and the two figures it is of, to 4
    decimals (not "0.1233 >= 0.100972")."""
    o1 = ratio_at_least("O1, planned / random", 0.12328790333450386, 0.10097224285911764)
    rmse = ratio_at_most("validation RMSE, calibrated / nominal", 0.0197906, 2.61908, unit="mm")
    vda = ratio_at_most("VDA 5 capability 2 U95 / T", 0.1405, 1.0, 0.3, "mm")
    assert check_row(o1) == "| O1, planned / random (0.1233 / 0.1010) | 1.2210 | >= 1.0000 | yes |"
    assert check_row(rmse) == (
        "| validation RMSE, calibrated / nominal (0.0198 mm / 2.6191 mm) | 0.0076 | <= 1.0000 "
        "| yes |"
    )
    assert check_row(vda) == (
        "| VDA 5 capability 2 U95 / T (0.1405 mm / 1.0000 mm) | 0.1405 | <= 0.3000 | yes |"
    )
    assert not ratio_at_least("O1, planned / random", 0.09, 0.1).ok


def test_figures_stated_without_a_limit_are_not_counted_as_checks(tmp_path: Path) -> None:
    """The workspace error's mean, largest and 95th percentile sit in the checks table, in mm
    at the RMSE's precision, with no limit and no verdict; "checks passed" counts checks."""
    journal = Journal(tmp_path, SETUP)
    _finish(
        journal,
        "workspace",
        at_most("workspace RMSE", 0.0386776, 0.2, "mm", fmt=MM),
        stated("workspace error, mean", 0.0366635, "mm", MM),
        stated("workspace error, largest (V007)", 0.0607862, "mm", MM),
    )
    md = markdown(journal)
    assert "| workspace RMSE | 0.0387 mm | <= 0.2000 mm | yes |" in md
    assert "| workspace error, mean | 0.0367 mm | - | - |" in md
    assert "| workspace error, largest (V007) | 0.0608 mm | - | - |" in md
    assert "| 10 | workspace | passed | 1/1 | 1.5 | 1 |" in md
    assert check_line(stated("workspace error, mean", 0.0366635, "mm", MM)) == (
        "     workspace error, mean: 0.0367 mm"
    )


def test_pf_ps_sd_say_what_they_are_the_largest_of_and_where() -> None:
    """PF the largest of the positions' ranges (a range: no sign, no "+-"), |PS| of the
    positions, |SD| of the 36 pairs, each naming its position or pair; SD's limit with the
    robot's share in it."""
    names = [name for name, _ in POSITIONS]
    pf = np.full(9, 0.09)
    pf[names.index("far")] = 0.1231
    ps = np.full(9, 0.005)
    ps[names.index("near")] = -0.0171
    pairs = np.column_stack(np.triu_indices(9, k=1)).astype(np.intp)
    sd = np.full(36, 0.01)
    worst = next(i for i, (a, b) in enumerate(pairs) if (names[a], names[b]) == ("left", "far"))
    sd[worst] = -0.0916
    acc = Acceptance(pf, ps, sd, pairs, AcceptanceLimits(0.15, 0.025, 0.015, 0.104))
    rows = [check_row(c) for c in figure_checks(acc, names)]
    assert rows == [
        "| probing error form PF, the largest of 9 positions' ranges (far) | 0.1231 mm "
        "| <= 0.1500 mm | yes |",
        "| probing error size \\|PS\\|, the largest of 9 positions (near) | 0.0171 mm "
        "| <= 0.0250 mm | yes |",  # "|" escaped: no column of its own
        "| sphere-spacing error \\|SD\\|, the largest of 36 pairs (left - far) | 0.0916 mm "
        "| <= 0.1190 mm (0.0150 + the robot's share 0.1040) | yes |",
    ]
    assert acc.message.startswith(
        "PF 123.1 um, the largest of 9 positions' ranges, within 150.0 um; "
        "PS -17.1 um, the largest |PS| of 9 positions, within +-25.0 um; "
        "SD -91.6 um, the largest |SD| of 36 pairs, within +-119.0 um"
    )
