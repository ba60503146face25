"""A cell started without a commissioning says so (issue 51, item 1): its status showed "U95
11 mm, CANNOT VOUCH" and nothing else. The parameters in force came from no calibration of
this cell (the nominal model): the status reply's `uncommissioned` says when the first
calibration comes (the good measurements its rolling set still needs, about how many windows),
`rvis status`'s accuracy line says it beside the U95; once a calibration of the cell is in
force it is gone."""

from __future__ import annotations

from pathlib import Path

from app.config.line import RecalibSettings
from app.line.states import accuracy_text
from fakes.devices import ClampCycle
from tests.line.helpers import SCALE, line_settings, make_line


def test_an_uncommissioned_cell_says_so_and_when_its_first_calibration_comes(
    tmp_path: Path,
) -> None:
    recalib = RecalibSettings(estimator="batch", rolling_size=24, holdout_size=4, every_n=8)
    cycle = ClampCycle(period_s=40.0, window_s=32.0, beat_s=0.5, time_scale=SCALE)
    settings = line_settings(window_s=32.0, slots_per_window=8)
    ln = make_line(tmp_path, cycle=cycle, line=settings, recalib=recalib)
    ln.start()
    try:
        ln.windows(1)
        status = ln.service.status()
        ok = status["measurements"]["ok"]
        assert 0 < ok < 28
        first = status["uncommissioned"]
        assert first["measurements_needed"] == 28 - ok  # the rolling set: 24 + 4 held out
        assert first["windows_needed"] == -(-(28 - ok) // 8)  # 8 slots a window
        assert first["text"] == (
            f"the first calibration comes after {28 - ok} more good measurements (about"
            f" {first['windows_needed']} windows)"
        )
        line = accuracy_text(status)
        assert line.endswith(f"; not commissioned: {first['text']}"), line
        assert "CANNOT VOUCH" in line or "vouched for" in line
        ln.wait(lambda e: e["event"] == "parameters_applied", 60.0)
        assert ln.service.status()["uncommissioned"] is None
    finally:
        ln.close()
