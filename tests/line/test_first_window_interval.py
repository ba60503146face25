"""The first window's body belongs to the accuracy interval it opens (issue 51, item 1): on the
real clock the interval of a cell that cannot vouch for its first window started 1 ms after that
window opened, so `rvis state suspects` left out its body.

The window's row is stored at the PLC's rising edge (app/line/cycle.py `WindowWatch.poll` ->
`WindowLoop._store_clamped`); `WindowLoop._window` then reads the clock again for the window's
`t_open` (app/line/window_loop.py), which a real clock had moved on by the time the row was
committed; an interval with no measurement before it started at that `t_open`
(`WindowLoop._state_accuracy`), after its own window. Now `t_open` is the rising edge's. On
the virtual clock nothing passes in between: here the row's commit takes a millisecond, as
SQLite's synchronous commit does on a disk."""

from __future__ import annotations

from pathlib import Path

from app.config.line import RecalibSettings
from tests.line.helpers import line_settings, make_line


def test_the_first_windows_body_is_in_the_interval_it_opens(tmp_path: Path) -> None:
    ln = make_line(
        tmp_path,
        line=line_settings(plc_body_id="u32"),
        recalib=RecalibSettings(estimator="batch", accuracy_limit_mm=0.001),  # never vouched
    )
    ln.plc.body_format = "u32"
    store = ln.service.store
    add_window = store.add_window

    def committed_in_a_millisecond(t: float, body_id: int | str | None) -> int:
        row = add_window(t, body_id)
        ln.clock.elapse(0.001)
        return row

    store.add_window = committed_in_a_millisecond  # type: ignore[method-assign]
    ln.start()
    try:
        ln.windows(1)
        [first] = store.windows()[:1]
        [interval] = store.suspects()
        assert interval["t_start"] <= first["t"]
        assert first["body_id"] in interval["bodies"]
    finally:
        ln.close()
