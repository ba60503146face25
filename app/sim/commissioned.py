"""A simulated cell commissioned by the script of `rvis commission --sim --geometric` (every step
confirmed), for the experiments that start from a commissioned cell (maintenance, the body's
gauge studies): the procedure's Context fields on the simulated line and its steps run as an
engineer would run them again after a devices step that failed under load."""

from __future__ import annotations

from contextlib import ExitStack
from typing import Any

from app.commission.context import Context
from app.commission.journal import Journal
from app.commission.sequence import run_sequence
from app.config import CellConfig
from app.errors import RvisError
from app.line.launch import hold_state
from app.line.statedir import StateDir
from app.sim.commission import SimCommissioning

#: runs again of a commissioning whose devices step failed (a simulated camera's frame lost
#: under load is not the seed's cell failing)
DEVICE_RETRIES = 2


def quiet(line: str) -> None:
    """The experiment's steps say nothing (their reports hold it all)."""


def commission_simulated(
    cfg: CellConfig, state: StateDir, seed: int, geometric: bool = True
) -> float:
    """The cell commissioned on the simulated line (every step of `rvis commission --sim
    [--geometric]`); the robot's time it took [s]."""
    with ExitStack() as stack:
        held = stack.enter_context(hold_state(state.root, str(cfg.service.operators_group)))
        sim = stack.enter_context(SimCommissioning(cfg, seed, geometric=geometric))
        ctx = Context(**scripted_fields(sim, cfg, held, quiet))
        setup = {"simulated": True, "seed": seed, "geometric": geometric}
        journal = Journal(held.commission, setup)
        failed = run_steps(ctx, journal)
        if failed is not None:
            raise RvisError(
                f"the simulated cell of seed {seed} did not pass its commissioning (step"
                f" {failed}: {held.commission_report}): another seed"
            )
        return ctx.robot_s


def scripted_fields(
    sim: SimCommissioning, cfg: CellConfig, held: StateDir, say: Any
) -> dict[str, Any]:
    """A guided procedure's Context fields on the simulated line, every question answered yes
    (the experiment's procedures: the station opened through the real drivers)."""
    cfg_plc, station = sim.open_station(cfg)
    fields = {"cfg": cfg_plc, "state": held, "station": station, "confirm": lambda _: True}
    return fields | {"say": say, **sim.context_fields()}


def run_steps(ctx: Any, journal: Journal) -> str | None:
    """A procedure's steps (`run_sequence`), run again from a failed devices step up to
    DEVICE_RETRIES times, as the engineer would (the journal continues there): a simulated
    camera's frame lost on a loaded loopback is not the seed's cell failing."""
    failed = run_sequence(ctx, journal)
    for _ in range(DEVICE_RETRIES):
        if failed != "devices":
            break
        failed = run_sequence(ctx, journal)
    return failed
