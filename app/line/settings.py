"""What the service needs besides its devices, clock, plan and spheres, gathered from the cell
file: each part is a section of app.config.line as it is declared there (the one declaration
of every setting), and the gates are calib.gate_limits.Gates (calib.gate_limits.INLINE with
the file's values, RMS and condition limits from [calibration]).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.config.cell import RobotSection, SensorSection, gates_of
from app.config.devices import ResultsSection
from app.config.line import (
    DriftSettings,
    LineSettings,
    OpcUaSettings,
    OperationsSettings,
    RecalibSettings,
    SweepSettings,
)
from app.config.section import project
from app.state_defaults import DEFAULT_ROOT
from calib.gate_limits import INLINE, Gates

__all__ = ["ServiceSettings", "from_cell"]


@dataclass(frozen=True)
class ServiceSettings:
    """The service's settings: its state directory (resolved) and the sections it uses."""

    state_dir: Path = Path(DEFAULT_ROOT)
    ops: OperationsSettings = field(default_factory=OperationsSettings)
    line: LineSettings = field(default_factory=LineSettings)
    sweep: SweepSettings = field(default_factory=SweepSettings)
    gates: Gates = INLINE
    drift: DriftSettings = field(default_factory=DriftSettings)
    recalib: RecalibSettings = field(default_factory=RecalibSettings)
    opcua: OpcUaSettings = field(default_factory=OpcUaSettings)
    # the sensor's measuring volume [mm]: standoff, half field of view x and y, half depth
    # ([sensor]; where a step's correction must hold, not only where the spheres appear)
    measuring_volume_mm: tuple[float, float, float, float] = (130.0, 18.5, 13.5, 5.0)
    # the sensor's acceptance limit on PS ([sensor] max_ps_mm), charted in-line
    max_ps_mm: float = SensorSection.max_ps_mm
    # the robot's ISO 9283 pose repeatability RP ([robot] repeatability_mm), by which a
    # body's views are chosen (app.inspect.views)
    repeatability_mm: float = RobotSection.repeatability_mm
    # a sphere centre's sd from one sweep, the sensor's own ([sensor] centre_sd_mm): with RP,
    # a sphere measurement's noise (app.line.estimate.sphere_sigma_mm)
    sensor_centre_sd_mm: float = SensorSection.centre_sd_mm
    # the sensor's edge placement allowances in a size's U95 ([sensor] edge_u_mm, a round
    # hole's; edge_u_slot_mm, a slot's)
    sensor_edge_u_mm: float = SensorSection.edge_u_mm
    sensor_edge_u_slot_mm: float = SensorSection.edge_u_slot_mm
    # [results]: the folder each body's AQDEF file goes to (None: none), the station, the days
    # the bodies are kept (0: for ever)
    results_dir: Path | None = None
    station: tuple[str, str] = ("rvis", "rvis in-line inspection cell")
    results_keep_days: float = ResultsSection.keep_days


def from_cell(cfg: Any, state_dir: str | Path | None = None) -> ServiceSettings:
    """ServiceSettings of a resolved cell (app.config.CellConfig): [line], [sweep], [drift],
    [service] (operations, recalibration, in-line gates), [calibration]'s RMS and condition
    limits and [opcua]; `state_dir` overrides [service] state_dir."""
    svc = cfg.service
    limits = {k: cfg.calibration[k] for k in ("max_rms_mm", "max_condition")}
    return ServiceSettings(
        state_dir=Path(state_dir if state_dir is not None else svc.state_dir),
        ops=project(OperationsSettings, svc),
        line=cfg.line,
        sweep=cfg.sweep,
        gates=gates_of({**dict(svc), **limits}, INLINE),
        drift=cfg.drift,
        recalib=project(RecalibSettings, svc),
        opcua=cfg.opcua,
        measuring_volume_mm=(
            float(cfg.sensor.standoff_mm),
            float(cfg.sensor.half_fov_x_mm),
            float(cfg.sensor.half_fov_y_mm),
            float(cfg.sensor.half_depth_mm),
        ),
        max_ps_mm=float(cfg.sensor.max_ps_mm),
        repeatability_mm=float(cfg.robot.repeatability_mm),
        sensor_centre_sd_mm=float(cfg.sensor.centre_sd_mm),
        sensor_edge_u_mm=float(cfg.sensor.edge_u_mm),
        sensor_edge_u_slot_mm=float(cfg.sensor.edge_u_slot_mm),
        results_dir=_results_dir(cfg, state_dir),
        station=(str(cfg.results.station), str(cfg.results.station_description)),
        results_keep_days=float(cfg.results.keep_days),
    )


def _results_dir(cfg: Any, state_dir: str | Path | None) -> Path | None:
    if not cfg.results.dir:
        return None
    root = Path(state_dir if state_dir is not None else cfg.service.state_dir)
    return root / cfg.results.dir
