"""The simulated line set up from the cell file and the state directory (app/sim/line_run.py):
its devices' settings, the world's sphere places and maintenance event, the geometric sensor,
the clock continued from the directory's history, and the service's settings on it."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.commission.files import TARGETS_FILE
from app.config import CellConfig
from app.formats.files import read_targets
from app.line.measure import GeometricSensor, Rejected
from app.line.settings import ServiceSettings, from_cell
from app.line.statedir import StateDir
from app.line.store import Store
from fakes.cell_spec import NotVisible
from fakes.line import SimLine, SimLineSetup
from fakes.truth import Knock, Maintenance, Warmup

F64 = NDArray[np.float64]


def simline_settings(
    cfg: CellConfig,
    *,
    geometric: bool,
    pace: float | None = None,
    start_epoch: float | None = None,
) -> SimLineSetup:
    """The simulated line of the cell file's [simline], in virtual time paced at `pace` sim
    seconds per real second (None: as fast as the CPU)."""
    s = cfg.simline
    knock = None
    if s.knock_at_s >= 0:
        knock = Knock(s.knock_at_s, s.knock_mm, s.knock_deg, s.knock_kind)
    return SimLineSetup(
        maintenance=maintenance_of(cfg),
        scale=pace,
        start_epoch=start_epoch,
        period_s=s.period_s,
        window_s=s.window_s,
        body_s=s.body_phase_s,
        beat_s=s.beat_s,
        warmup=Warmup(s.warmup_k, s.warmup_tau_s, s.warmup_start_s) if s.warmup_k else None,
        knock=knock,
        camera=not geometric,
        n_validation=s.n_validation,
        camera_readout_s=s.camera_readout_s,
        galvo_settle_s=s.galvo_settle_s,
        body_format="serial8" if cfg.line.plc_body_id == "serial8" else "u32",
    )


def world_of(cfg: CellConfig, state_dir: str | Path) -> CellConfig:
    """The cell file with the simulated world's own sphere places: a commissioned directory's
    are what its commissioning's tracker measured (`commission/targets.csv`, the world's to
    its noise), which a maintenance's hand-over never changes; the cell file's own are the
    service's belief (after a fixture's renewal, the spheres' new places: the world must not
    move them a second time)."""
    path = StateDir(state_dir).commission / TARGETS_FILE
    if not path.is_file():
        return cfg
    return dataclasses.replace(cfg, spheres_part_mm=read_targets(path))


def maintenance_of(cfg: CellConfig) -> Maintenance | None:
    """The cell file's maintenance event of the simulated world ([simline] maintenance_*)."""
    s = cfg.simline
    if s.maintenance_at_s < 0:
        return None
    return Maintenance(
        s.maintenance_at_s,
        s.maintenance_kind,
        axis=s.maintenance_axis,
        sphere=s.maintenance_sphere,
        shift_mm=s.maintenance_mm or None,
        frame=s.maintenance_frame,
        tilt_deg=s.maintenance_deg or None,
    )


def geometric_sensor(line: SimLine, sweep_s: float = 0.0) -> GeometricSensor:
    """The simulated line's geometric sensor: the true centre plus the sensor's noise; out of
    the sensor's view (a knocked sensor, a moved sphere) a rejected measurement, as the
    rendered path's vision checks reject it."""

    def centre(target: str) -> Any:
        try:
            return line.geometric_centre(target, sweep_s)
        except NotVisible as exc:
            raise Rejected(f"NotVisible: {exc}") from exc

    return GeometricSensor(centre, sweep_s)


def continued_epoch(state_dir: Path, start_epoch: float | None = None) -> tuple[float, float]:
    """(the Unix time a simulated line's clock starts at, the world's time then [s]).

    The clock starts at `start_epoch` (default now), or just after the last time the state
    directory's database records when that is later (a run before ran ahead). The world
    continues where the last run left it: its time is the span from the first simulated
    line's start on this directory (its first `started` event) to the end of its history (the
    world stands while no line runs), 0 on a new directory."""
    now = time.time() if start_epoch is None else start_epoch
    db = StateDir(state_dir).db
    if not db.is_file():
        return now, 0.0
    store = Store.read_only(db)
    try:
        last = store.last_time()
        started = store.events("started")
    finally:
        store.close()
    if last is None:
        return now, 0.0
    world_s = last + 1.0 - float(started[0]["t"]) if started else 0.0
    return max(now, last + 1.0), max(world_s, 0.0)


def with_simulated_plc(cfg: CellConfig) -> CellConfig:
    """The cell as the simulated line's devices are: its PLC writes the cell temperature in
    word 2 (`[line] plc_temperature` on, whatever the cell file says) and counts bodies, the
    body number in words 3-4 (`[line] plc_body_id` "u32" unless the cell file says "serial8":
    then the simulated PLC writes serials), and leaves each body [simline] body_s for its
    features (`[line] body_window_s`)."""
    body = "u32" if cfg.line.plc_body_id == "none" else cfg.line.plc_body_id
    line = dataclasses.replace(cfg.line, plc_temperature=True, plc_body_id=body)
    if cfg.simline.body_phase_s > 0:  # the body's phase as the simulated PLC runs it
        line = dataclasses.replace(line, body_window_s=cfg.simline.body_phase_s)
    return dataclasses.replace(cfg, line=line)


def service_settings(cfg: CellConfig, state_dir: Path) -> ServiceSettings:
    """The cell's service settings on the simulated line: the clamp window's length, the PLC
    poll of [simline] poll_s (in virtual time every poll is a real exchange: it sets how fast
    a run goes) and a window margin that takes in a rising edge seen up to a poll late."""
    s = from_cell(cfg, state_dir)
    poll_s = cfg.simline.poll_s
    line = replace(
        s.line,
        window_s=cfg.simline.window_s,
        margin_s=s.line.margin_s + poll_s,
        poll_s=poll_s,
        heartbeat_timeout_s=max(s.line.heartbeat_timeout_s, 4.0 * poll_s),
    )
    return replace(s, line=line)
