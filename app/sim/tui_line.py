"""`rvis tui --sim`: the simulated line and its service in the TUI's own process.

`simulated_service` starts SimulatedLineRun (the service on the simulated line, through the real
drivers over loopback) in a background thread with its control socket in the state directory;
the TUI then attaches over that socket exactly as to a real service. Leaving the context stops
the service and the line (only this command does that: `rvis tui` alone never stops a service).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, replace
from multiprocessing import resource_tracker
from pathlib import Path
from typing import Literal

from app.config import CellConfig
from app.line.launch import hold_state, serving
from app.sim.line_run import SimulatedLineRun


@dataclass(frozen=True)
class TuiSimSettings:
    """How `rvis tui --sim` runs the simulated line (defaults: responsive on a laptop).

    geometric: skip rendering (sphere centres from the truth plus noise); seed: the
    simulation's seed (None: [simulation] seed); scale: the pace of the line's virtual time,
    simulated seconds per real second (None: [simline] scale); mode: the service's
    recalibration mode (None: [service]), e.g. "approve" to show the approval flow;
    start_at_s: the sim time the service starts at (the line's clock is advanced that far
    first, e.g. into the cell's warm-up, so that it has drifted from the commissioning)."""

    geometric: bool = True
    seed: int | None = None
    scale: float | None = None
    mode: Literal["auto", "approve"] | None = None
    start_at_s: float = 0.0


@contextlib.contextmanager
def simulated_service(
    cfg: CellConfig, state_dir: str | Path, settings: TuiSimSettings = TuiSimSettings()
) -> Iterator[SimulatedLineRun]:
    """The simulated line and its service running, socket at STATE_DIR/rvis.sock."""
    if settings.scale is not None:
        cfg = replace(cfg, simline=replace(cfg.simline, scale=settings.scale))
    seed = cfg.simulation.seed if settings.seed is None else settings.seed
    run = SimulatedLineRun(  # attended: the operator's terminal resets a FAULT
        cfg,
        state_dir,
        seed=seed,
        geometric=settings.geometric,
        pace=cfg.simline.scale,
        attended=True,
    )
    if settings.mode is not None:
        run.settings = replace(
            run.settings, recalib=replace(run.settings.recalib, mode=settings.mode)
        )
    # the recalibrations run in a process pool; its resource tracker must start while stdio is
    # still the real one (a Textual app replaces sys.stderr with one that has no file number)
    resource_tracker.ensure_running()
    with hold_state(state_dir), run, serving(run.service):
        run.clock.advance(settings.start_at_s)
        run.start_service()
        yield run
