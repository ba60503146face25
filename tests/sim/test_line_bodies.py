"""The bodies of a suspect interval, end to end (issue 28 item 4): the simulated line's PLC
counts bodies (period k clamps body 100001 + k, its id in the PLC's body id words over Modbus),
the service reads the id at each window's rising edge and stores it with the window, and after
a knock `rvis state suspects --json` names exactly the bodies whose windows opened inside the
interval, as the PLC's own schedule says, in the PLC's format (a number or a serial)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from app.commands.cli import main
from app.config import CellConfig
from app.sim.line_run import SimulatedLineRun
from fakes.line_faults import window_at

WINDOWS = 12
KNOCK_AT_S = 244.0  # between the 6th window's close (240 s) and the 7th's opening (248 s)


@pytest.mark.parametrize(
    ("fmt", "first"), [("u32", 100001), ("serial8", "B0100001")], ids=["u32", "serial8"]
)
def test_rvis_state_suspects_names_exactly_the_bodies_clamped_inside_the_interval(
    cfg: CellConfig, tmp_path: Path, capsys: pytest.CaptureFixture[str], fmt: str, first: Any
) -> None:
    # two slots a window, also while a jump is open: the jump's evidence comes over several
    # windows, so that its interval spans several bodies (with 8 slots a window the knock is
    # found and corrected within its own window: an interval of one body, which names nothing
    # to tell apart); no warm-up (its drift is not the knock); the batch estimator; the
    # plant's accuracy limit well above the commissioned cell's U95, so that the knock's is
    # the only interval
    knocked = dataclasses.replace(
        cfg,
        service=dataclasses.replace(cfg.service, estimator="batch", accuracy_limit_mm=0.3),
        line=dataclasses.replace(
            cfg.line, slots_per_window=2, step_slots_per_window=2, plc_body_id=fmt
        ),
        simline=dataclasses.replace(
            cfg.simline, warmup_k=0.0, period_s=40.0, window_s=32.0, knock_at_s=KNOCK_AT_S
        ),
    )
    state = tmp_path / "state"
    events: list[dict[str, Any]] = []
    with SimulatedLineRun(knocked, state, seed=0, geometric=True) as run:
        run.run_windows(WINDOWS, on_event=events.append)
        line, epoch = run.line, run.clock.start_epoch
        poll_s = run.settings.line.poll_s
        status = run.service.status()
        stored = run.service.store.windows()
    assert line.window_body(0) == first  # the PLC's count, in its format
    # what the PLC clamped when: period k's body, its window opening at window_bounds_s(k)
    clamped = {k: (line.window_bounds_s(k)[0], line.window_body(k)) for k in range(WINDOWS + 1)}

    assert main(["state", "suspects", "--json", "--state-dir", str(state)]) == 0
    (interval,) = json.loads(capsys.readouterr().out)
    # closed at the correction: back at its level before the step (the step group's fast
    # correction or the full recalibration, whichever is in force when the recovery test passes),
    # or vouched for (U95 within the limit on the measurements after it)
    assert interval["state"] == "closed" and interval["end_reason"] in ("step", "batch", "vouched")
    t_start, t_end = interval["t_start"] - epoch, interval["t_end"] - epoch
    assert t_start < KNOCK_AT_S < t_end
    inside = [body for opens, body in clamped.values() if t_start <= opens <= t_end]
    assert len(inside) >= 2 and interval["bodies"] == inside
    # no window opened within a poll of either end: the expected set is unambiguous
    assert all(abs(opens - t) > poll_s for opens, _ in clamped.values() for t in (t_start, t_end))

    # every window is stored with the body the PLC clamped in it, seen within a poll of its edge
    assert len(stored) >= WINDOWS
    for w in stored:
        k = window_at(line.settings.cycle, w["t"] - epoch)
        assert k is not None and w["body_id"] == clamped[k][1]
        assert 0 <= w["t"] - epoch - clamped[k][0] <= poll_s + 1e-9
    # the events and the status reply carry the same bodies (the open event: those so far)
    told = [e for e in events if e["event"] == "suspect_interval"]
    assert told[-1]["state"] == "closed" and told[-1]["bodies"] == inside
    assert told[0]["state"] == "open" and told[0]["bodies"]
    assert told[0]["bodies"] == inside[: len(told[0]["bodies"])]
    assert status["suspect_intervals"][-1]["bodies"] == inside
