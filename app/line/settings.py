"""The service's settings: frozen dataclasses with defaults, one per concern.

Names follow the cell file's `[service]` and `[line]` sections (app/config.py) where those exist;
`from_cell(cfg)` reads them. Times are in the clock's seconds, angles at this boundary in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np

from calib.gates import Gates

T = TypeVar("T")
JOINT_SPEED_DEG_S = (175.0, 175.0, 175.0, 250.0, 250.0, 355.0)  # M-710iC/50 data sheet
HOME_DEG = (0.0, 0.0, 0.0, 0.0, -90.0, 0.0)


@dataclass(frozen=True)
class LineSettings:
    """The PLC handshake and the motion-time model of one window."""

    poll_s: float = 0.01
    heartbeat_timeout_s: float = 3.0
    override_pct: int = 100
    speed_pct: float = 100.0
    joint_speed_deg_s: tuple[float, ...] = JOINT_SPEED_DEG_S
    accel_s: float = 0.4  # per move: acceleration and deceleration allowance
    settle_s: float = 0.2  # per move: settling at FINE
    home_deg: tuple[float, ...] = HOME_DEG
    home_tol_deg: float = 0.05
    window_s: float = 8.0  # how long a clamp window lasts (the PLC sends only the bit)
    margin_s: float = 0.5  # kept free at the end of every window
    slots_per_window: int = 1
    plc_temperature: bool = False  # the PLC provides the cell temperature (word 2)
    plc_temp_min_c: float = 5.0  # plausible cell air temperatures [degC]; outside: none
    plc_temp_max_c: float = 50.0

    def __post_init__(self) -> None:
        if len(self.joint_speed_deg_s) != 6 or len(self.home_deg) != 6:
            raise ValueError("joint_speed_deg_s and home_deg need 6 values")
        if not (self.poll_s > 0 and self.window_s > 0 and 1 <= self.override_pct <= 100):
            raise ValueError("poll_s, window_s > 0 and override_pct in 1..100")
        if self.slots_per_window < 1:
            raise ValueError("slots_per_window must be >= 1")
        if not self.plc_temp_min_c < self.plc_temp_max_c:
            raise ValueError("plc_temp_min_c must be below plc_temp_max_c")


@dataclass(frozen=True)
class SweepSettings:
    """The galvo sweep of one measurement: commands [V] evenly over +-span_v."""

    n_frames: int = 24
    span_v: float = 3.2
    frame_s: float = 0.05  # per frame: set the galvo, settle, expose, transfer (estimate)
    grab_timeout_s: float = 1.0

    def commands_v(self) -> tuple[float, ...]:
        return tuple(float(v) for v in np.linspace(-self.span_v, self.span_v, self.n_frames))

    @property
    def duration_s(self) -> float:
        return self.n_frames * self.frame_s


@dataclass(frozen=True)
class GateSettings:
    """Gates of an in-line identification (calib.gates) plus the held-out comparison."""

    max_rms_mm: float = 0.25
    max_condition: float = 1000.0
    max_joint_change_mm: float = 5.0
    max_joint_change_deg: float = 1.0
    max_sensor_change_mm: float = 5.0
    max_sensor_change_deg: float = 2.0
    max_base_change_mm: float = 5.0
    max_base_change_deg: float = 1.0
    max_holdout_ratio: float = 1.0  # candidate RMS / current RMS on the held-out measurements

    def calib_gates(self) -> Gates:
        return Gates(
            max_rms_mm=self.max_rms_mm,
            max_condition=self.max_condition,
            max_joint_change_mm=self.max_joint_change_mm,
            max_joint_change_rad=float(np.radians(self.max_joint_change_deg)),
            max_sensor_change_mm=self.max_sensor_change_mm,
            max_sensor_change_rad=float(np.radians(self.max_sensor_change_deg)),
            max_base_change_mm=self.max_base_change_mm,
            max_base_change_rad=float(np.radians(self.max_base_change_deg)),
        )


@dataclass(frozen=True)
class DriftSettings:
    """EWMA and CUSUM of the residuals (REFERENCE.md "Drift charts")."""

    ewma_lambda: float = 0.2
    ewma_l: float = 3.0  # limit in sigmas of the EWMA's asymptotic spread
    cusum_k: float = 0.5  # slack in sigmas
    cusum_h: float = 5.0  # decision interval in sigmas
    baseline_n: int = 16  # samples after each applied calibration that set mean and sigma
    min_sigma_mm: float = 0.01  # floor of the learned sigma (noise-free baselines)

    def __post_init__(self) -> None:
        if not (0 < self.ewma_lambda <= 1 and self.baseline_n >= 2):
            raise ValueError("ewma_lambda in (0, 1] and baseline_n >= 2")


@dataclass(frozen=True)
class RecalibSettings:
    """When and how the service recalibrates."""

    mode: Literal["auto", "approve"] = "auto"
    rolling_size: int = 24
    holdout_size: int = 4
    every_n: int = 24  # new measurements between scheduled recalibrations
    max_nfev: int = 200
    # "batch": identification on the rolling set; "sequential": app.line.inline_seq
    estimator: Literal["batch", "sequential"] = "batch"
    seq_apply_every: int = 8  # accepted updates between two candidates
    seq_measurement_std_mm: float = 0.025
    seq_drift_mm: float = 0.002  # random-walk standard deviation per update
    seq_drift_rad: float = 2e-6
    seq_drift_extra: float = 0.0
    seq_knock_mm: float = 0.5  # added to the standard deviations when a step is flagged
    seq_knock_rad: float = 1e-3
    seq_prior_mm: float = 0.5  # prior of parameters without an identification's covariance
    seq_prior_rad: float = 1e-3
    seq_max_std_mm: float = 0.025  # after a step: predicted uncertainty before a candidate
    # "cycle": the plan's configurations in turn; "adaptive" (sequential only): the most
    # informative configuration that fits the window
    schedule: Literal["cycle", "adaptive"] = "cycle"

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "approve"):
            raise ValueError("mode must be auto or approve")
        if self.estimator not in ("batch", "sequential") or self.seq_apply_every < 1:
            raise ValueError("estimator must be batch or sequential, seq_apply_every >= 1")
        if self.schedule == "adaptive" and self.estimator != "sequential":
            raise ValueError("schedule = adaptive needs estimator = sequential")
        if self.rolling_size < 10 or self.holdout_size < 1 or self.every_n < 1:
            raise ValueError("rolling_size >= 10, holdout_size >= 1, every_n >= 1")


@dataclass(frozen=True)
class OpcUaSettings:
    """The OPC UA server of the service (the cell file's `[opcua]`, app.line.opcua)."""

    enabled: bool = False
    endpoint: str = "opc.tcp://127.0.0.1:4840/rvis"
    security_policy: str = "none"  # or a signing-and-encrypting policy (endpoint.py)
    allow_anonymous: bool = False  # beyond loopback; on loopback anonymous is allowed
    allow_ack: bool = False  # acknowledging alarms from OPC UA (audited as an operator's ack)
    machine_name: str = "rvis-cell"
    manufacturer: str = "rvis"
    model: str = "RVIS in-line self-calibration, FANUC M-710iC/50 + laser-line sensor"
    serial_number: str = ""  # "": the host's name
    product_instance_uri: str = ""  # "": urn:<manufacturer>:<serial number>:<machine name>


@dataclass(frozen=True)
class ServiceSettings:
    """Everything the service needs besides its devices, clock, plan and spheres."""

    state_dir: Path = Path("rvis-state")
    raw_sweeps_keep: int = 0
    operators_group: str = ""  # "" : the state directory is 0750, else 0770 with this group
    min_free_mb: float = 200.0  # below this free space under the state directory: an alarm
    events_keep_days: float = 90.0  # events older than this are deleted (0: kept for ever)
    # the full document of a rejected calibration is dropped after this (its gates, figures and
    # reason stay; 0: kept for ever)
    rejected_keep_days: float = 30.0
    line: LineSettings = field(default_factory=LineSettings)
    sweep: SweepSettings = field(default_factory=SweepSettings)
    gates: GateSettings = field(default_factory=GateSettings)
    drift: DriftSettings = field(default_factory=DriftSettings)
    recalib: RecalibSettings = field(default_factory=RecalibSettings)
    opcua: OpcUaSettings = field(default_factory=OpcUaSettings)


def _section(cls: type[T], section: Any) -> T:
    """A settings dataclass from the cell section of the same keys (tuples kept as tuples)."""
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    return cls(**{k: v for k, v in dict(section).items() if k in names})


def from_cell(cfg: Any, state_dir: str | Path | None = None) -> ServiceSettings:
    """ServiceSettings from a resolved cell configuration (app.config.CellConfig): [line],
    [sweep], [drift], [service] (recalibration and in-line gates), [calibration] (RMS and
    condition limits) and [opcua]."""
    svc, cal = cfg.service, cfg.calibration
    gates = _section(
        GateSettings, {**dict(svc), **{k: cal[k] for k in ("max_rms_mm", "max_condition")}}
    )
    return ServiceSettings(
        state_dir=Path(state_dir if state_dir is not None else svc.state_dir),
        raw_sweeps_keep=int(svc.raw_sweeps_keep),
        operators_group=str(svc.operators_group),
        min_free_mb=float(svc.min_free_mb),
        events_keep_days=float(svc.events_keep_days),
        rejected_keep_days=float(svc.rejected_keep_days),
        line=_section(LineSettings, cfg.line),
        sweep=_section(SweepSettings, cfg.sweep),
        gates=gates,
        drift=_section(DriftSettings, cfg.drift),
        recalib=_section(RecalibSettings, svc),
        opcua=_section(OpcUaSettings, cfg.opcua),
    )
