"""Cell configuration: the cell TOML read once into frozen, typed, validated sections.

The embedded default is the simulated cell (spheres at the paper's Table 1 positions); a cell
file overrides any of its keys. Every section is a frozen dataclass whose fields are the keys,
their defaults the embedded cell and their metadata the checks (type, range, choices, length).
A wrong key, type or value is an InputError `file:line: [section] key: reason` (exit code 2),
with the close key name suggested on a typo. Sections also read like mappings
(`cfg.planning["criterion"]`), so code that merges them with command-line overrides keeps working.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from app.errors import InputError
from app.line.opcua.endpoint import SECURITY_POLICIES, endpoint_problem
from calib import robot as nominal_robot

F64 = NDArray[np.float64]
Vec = tuple[float, ...]

PAPER_TABLE1_BASE_MM = {
    "P1": (-647.14, 1254.27, -289.37),
    "P2": (1742.87, 1138.35, -260.87),
    "P3": (1428.57, -1347.92, 102.31),
    "P4": (-704.45, -1265.87, 680.54),
}
MAX_COORD_MM = 1e5
MAX_ANGLE_DEG = 720.0
# names of the choice lists live with the algorithms; importing calib/ here would load numpy-heavy
# modules for every command, so they are listed here and a test checks them against calib/
CRITERIA = ("O1", "O2", "O3", "O4", "O5", "I")
METHODS = ("detmax", "eae", "random")
PLACEMENTS = ("fixed", "sequential", "joint", "none")
LOSSES = ("linear", "huber", "soft_l1", "cauchy", "arctan")
ROBOT_MODELS = ("fanuc-m710ic50",)


def opt(
    default: Any,
    *,
    lo: float | None = None,
    hi: float | None = None,
    gt: float | None = None,
    choices: tuple[str, ...] | None = None,
    n: int | None = None,
) -> Any:
    """A config key: its default and its checks (inclusive lo/hi, exclusive gt, choices,
    vector length n)."""
    meta = {"lo": lo, "hi": hi, "gt": gt, "choices": choices, "n": n}
    if isinstance(default, list):
        return field(default=tuple(default), metadata=meta)
    if isinstance(default, dict):
        return field(default_factory=lambda: dict(default), metadata=meta)
    return field(default=default, metadata=meta)


class Section(Mapping[str, Any]):
    """Read-only mapping view of a section dataclass (keys = its fields)."""

    name: ClassVar[str] = ""

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys():
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())

    @classmethod
    def _keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]


_J = nominal_robot.JointLimits()


@dataclass(frozen=True)
class RobotSection(Section):
    name = "robot"
    model: str = opt("fanuc-m710ic50", choices=ROBOT_MODELS)
    joint_lower_deg: Vec = opt(list(map(float, _J.lower_deg)), lo=-720, hi=720, n=6)
    joint_upper_deg: Vec = opt(list(map(float, _J.upper_deg)), lo=-720, hi=720, n=6)


@dataclass(frozen=True)
class FramesSection(Section):
    name = "frames"
    part_base_xyz_mm: Vec = opt([1500.0, -2500.0, 700.0], lo=-1e5, hi=1e5, n=3)
    part_base_rotvec_deg: Vec = opt([0.0, 0.0, 90.0], lo=-360, hi=360, n=3)
    flange_sensor_xyz_mm: Vec = opt([0.0, -90.0, 160.0], lo=-2000, hi=2000, n=3)
    flange_sensor_rotvec_deg: Vec = opt([0.0, 0.0, 0.0], lo=-360, hi=360, n=3)


@dataclass(frozen=True)
class BasePlateSection(Section):
    name = "base_plate"
    x_min_mm: float = opt(-750.0, lo=-1e5, hi=1e5)
    x_max_mm: float = opt(750.0, lo=-1e5, hi=1e5)
    y_min_mm: float = opt(-750.0, lo=-1e5, hi=1e5)
    y_max_mm: float = opt(750.0, lo=-1e5, hi=1e5)


@dataclass(frozen=True)
class SensorSection(Section):
    name = "sensor"
    standoff_mm: float = opt(130.0, gt=0, hi=2000)
    half_fov_x_mm: float = opt(18.5, gt=0, hi=1000)
    half_fov_y_mm: float = opt(13.5, gt=0, hi=1000)
    half_depth_mm: float = opt(5.0, gt=0, hi=1000)
    sphere_radius_mm: float = opt(15.0, gt=0, hi=500)


@dataclass(frozen=True)
class SpheresSection(Section):
    name = "spheres"
    frame: str = opt("base", choices=("base", "part"))
    positions_mm: dict[str, Vec] = opt(PAPER_TABLE1_BASE_MM, lo=-1e5, hi=1e5, n=3)


@dataclass(frozen=True)
class SimulationSection(Section):
    name = "simulation"
    seed: int = opt(0, lo=0, hi=2**32 - 1)
    tracker_noise_mm: float = opt(0.01, lo=0, hi=10)
    sensor_noise_mm: float = opt(0.02, lo=0, hi=10)
    compliance: bool = opt(True)
    thermal: bool = opt(True)
    temp_c: float = opt(20.0, lo=-40, hi=80)


@dataclass(frozen=True)
class CalibrationSection(Section):
    """Identification and its quality gates (calib.gates): a result is used only when it
    converged, has rank 30, finite values, RMS <= max_rms_mm, condition <= max_condition and
    every parameter within the allowed change from its reference."""

    name = "calibration"
    model: str = opt("rigid", choices=("rigid", "compliant"))
    payload_kg: float = opt(0.0, lo=0, hi=500)
    nominal_compliance_rad_per_nm: float = opt(5e-8, lo=0, hi=1e-5)
    expansion_per_k: float = opt(11.5e-6, lo=0, hi=1e-4)
    identify_expansion: bool = opt(True)
    min_temp_span_k: float = opt(3.0, gt=0, hi=100)
    reference_temp_c: float = opt(20.0, lo=-40, hi=80)
    configs_per_sphere: int = opt(6, lo=1, hi=1000)
    loss: str = opt("linear", choices=LOSSES)
    max_rms_mm: float = opt(0.25, gt=0, hi=100)
    max_condition: float = opt(1000.0, gt=1)
    max_joint_change_mm: float = opt(5.0, gt=0, hi=1000)
    max_joint_change_deg: float = opt(1.0, gt=0, hi=180)
    max_sensor_change_mm: float = opt(20.0, gt=0, hi=1000)
    max_sensor_change_deg: float = opt(5.0, gt=0, hi=180)

    def gates(self) -> Any:
        """The calib.gates.Gates of this section (offline: the part->base pose unbounded)."""
        import math

        from calib.gates import Gates

        return Gates(
            max_rms_mm=self.max_rms_mm,
            max_condition=self.max_condition,
            max_joint_change_mm=self.max_joint_change_mm,
            max_joint_change_rad=math.radians(self.max_joint_change_deg),
            max_sensor_change_mm=self.max_sensor_change_mm,
            max_sensor_change_rad=math.radians(self.max_sensor_change_deg),
        )


@dataclass(frozen=True)
class PlanningSection(Section):
    name = "planning"
    criterion: str = opt("O1", choices=CRITERIA)
    method: str = opt("detmax", choices=METHODS)
    placement: str = opt("sequential", choices=PLACEMENTS)
    grid_step_deg: float = opt(5.0, gt=0, hi=90)
    search_step_deg: float = opt(30.0, gt=0, hi=90)
    max_tilt_deg: float = opt(80.0, lo=0, hi=90)
    fov_offsets: str = opt("spread", choices=("spread", "centre"))
    swarm_size: int = opt(50, lo=2, hi=10000)
    iterations: int = opt(30, lo=1, hi=10000)
    clearance_above_sphere_mm: float = opt(30.0, lo=0, hi=1e4)
    floor_z_mm: float = opt(-565.0, lo=-1e5, hi=1e5)
    clearance_above_floor_mm: float = opt(150.0, lo=0, hi=1e4)
    workspace_mm: Vec = opt([-2000.0, 2000.0, -2000.0, 2000.0], lo=-1e5, hi=1e5, n=4)
    reach_mm: float = opt(2000.0, gt=0, hi=1e5)
    plate_margin_mm: float = opt(50.0, lo=0, hi=1e4)
    min_separation_mm: float = opt(300.0, lo=0, hi=1e5)
    seed: int = opt(0, lo=0, hi=2**32 - 1)
    workers: int = opt(2, lo=1, hi=256)
    revisits: int = opt(0, lo=0, hi=10)


@dataclass(frozen=True)
class DevicesSection(Section):
    """Device URLs (drivers.registry); optional: without it every device is the fake. `trace`:
    every device's wire traffic to the state directory's trace/wire.jsonl (drivers.trace;
    one device alone: `?trace=1` in its URL), rotated at trace_max_mb, trace_keep old files."""

    name = "devices"
    robot: str = opt("fake://")
    camera: str = opt("fake://")
    galvo: str = opt("fake://")
    tracker: str = opt("fake://")
    plc: str = opt("fake://")
    trace: bool = opt(False)
    trace_max_mb: float = opt(10.0, gt=0, hi=10000)
    trace_keep: int = opt(5, lo=1, hi=1000)

    FAMILIES: ClassVar[tuple[str, ...]] = ("robot", "camera", "galvo", "tracker", "plc")

    def urls(self) -> dict[str, str]:
        """family -> device URL."""
        return {family: getattr(self, family) for family in self.FAMILIES}

    def traced(self) -> bool:
        """Whether any device is traced (the setting, or `trace=1` in a URL)."""
        from drivers.url import parse_url

        return self.trace or any(parse_url(u).flag("trace") for u in self.urls().values())

    def wire_trace(self, path: Any, *, every_device: bool | None = None) -> Any:
        """The drivers.trace.WireTrace at `path` these settings ask for, or None when off
        (`every_device`: trace every device, default: as `trace` says; the simulated line,
        whose URLs are its own, traces all of them when any tracing is asked for)."""
        if not self.traced():
            return None
        from drivers.trace import WireTrace

        return WireTrace(
            path,
            max_bytes=int(self.trace_max_mb * 2**20),
            keep=self.trace_keep,
            every_device=self.trace if every_device is None else every_device,
        )


@dataclass(frozen=True)
class ServiceSection(Section):
    """The in-line service (`rvis run`): where it keeps its state, how it recalibrates and the
    gates of an in-line identification (change bounds from the parameters in force, tighter
    than [calibration]'s offline ones; the candidate must also beat the parameters in force on
    held-out recent measurements by max_holdout_ratio)."""

    name = "service"
    state_dir: str = opt("rvis-state")
    mode: str = opt("auto", choices=("auto", "approve"))
    rolling_size: int = opt(24, lo=10, hi=100000)
    holdout_size: int = opt(4, lo=1, hi=1000)
    every_n: int = opt(24, lo=1, hi=100000)
    max_nfev: int = opt(200, lo=10, hi=10000)
    raw_sweeps_keep: int = opt(0, lo=0, hi=100000)
    # operations: the operators' group of the state directory ("": none, 0750), the free space
    # below which a warning alarm is raised, how long events and the documents of rejected
    # calibrations are kept (0: for ever)
    operators_group: str = opt("")
    min_free_mb: float = opt(200.0, lo=0, hi=1e7)
    events_keep_days: float = opt(90.0, lo=0, hi=36500)
    rejected_keep_days: float = opt(30.0, lo=0, hi=36500)
    max_joint_change_mm: float = opt(5.0, gt=0, hi=1000)
    max_joint_change_deg: float = opt(1.0, gt=0, hi=180)
    max_sensor_change_mm: float = opt(5.0, gt=0, hi=1000)
    max_sensor_change_deg: float = opt(2.0, gt=0, hi=180)
    max_base_change_mm: float = opt(5.0, gt=0, hi=1000)
    max_base_change_deg: float = opt(1.0, gt=0, hi=180)
    max_holdout_ratio: float = opt(1.0, gt=0, hi=10)
    estimator: str = opt("batch", choices=("batch", "sequential"))
    seq_apply_every: int = opt(8, lo=1, hi=100000)
    seq_measurement_std_mm: float = opt(0.025, gt=0, hi=10)
    seq_drift_mm: float = opt(0.002, lo=0, hi=10)
    seq_drift_rad: float = opt(2e-6, lo=0, hi=0.1)
    seq_drift_extra: float = opt(0.0, lo=0, hi=1)
    seq_knock_mm: float = opt(0.5, lo=0, hi=100)
    seq_knock_rad: float = opt(1e-3, lo=0, hi=1)
    seq_prior_mm: float = opt(0.5, gt=0, hi=100)
    seq_prior_rad: float = opt(1e-3, gt=0, hi=1)
    seq_max_std_mm: float = opt(0.025, gt=0, hi=10)
    schedule: str = opt("cycle", choices=("cycle", "adaptive"))


@dataclass(frozen=True)
class LineSection(Section):
    """The line handshake and motion-time model of the service's cycle."""

    name = "line"
    poll_s: float = opt(0.01, gt=0, hi=10)
    heartbeat_timeout_s: float = opt(3.0, gt=0, hi=600)
    override_pct: int = opt(100, lo=1, hi=100)
    speed_pct: float = opt(100.0, gt=0, hi=100)
    joint_speed_deg_s: Vec = opt([175.0, 175.0, 175.0, 250.0, 250.0, 355.0], gt=0, hi=2000, n=6)
    accel_s: float = opt(0.4, lo=0, hi=60)
    settle_s: float = opt(0.2, lo=0, hi=60)
    home_deg: Vec = opt([0.0, 0.0, 0.0, 0.0, -90.0, 0.0], lo=-720, hi=720, n=6)
    home_tol_deg: float = opt(0.05, gt=0, hi=5)
    window_s: float = opt(8.0, gt=0, hi=3600)
    margin_s: float = opt(0.5, lo=0, hi=60)
    slots_per_window: int = opt(1, lo=1, hi=100)
    # the PLC writes the cell temperature in its word 2 (off: the word is not read; a PLC
    # program that predates it leaves 0 there, which is not 0 degC)
    plc_temperature: bool = opt(False)
    # a reading outside this range is "no temperature" with an alarm, never a number
    plc_temp_min_c: float = opt(5.0, lo=-40, hi=100)
    plc_temp_max_c: float = opt(50.0, lo=-40, hi=100)


@dataclass(frozen=True)
class SweepSection(Section):
    """One measurement's galvo sweep: n_frames commands evenly over +-span_v [V]."""

    name = "sweep"
    n_frames: int = opt(24, lo=3, hi=1000)
    span_v: float = opt(3.2, gt=0, hi=10)
    frame_s: float = opt(0.05, gt=0, hi=10)
    grab_timeout_s: float = opt(1.0, gt=0, hi=60)


@dataclass(frozen=True)
class DriftSection(Section):
    """Drift charts of the residuals (REFERENCE.md): EWMA (lambda, limit L sigma) and upper
    CUSUM (slack k, decision h, in sigmas), sigma learned from baseline_n measurements after
    each applied calibration."""

    name = "drift"
    ewma_lambda: float = opt(0.2, gt=0, hi=1)
    ewma_l: float = opt(3.0, gt=0, hi=10)
    cusum_k: float = opt(0.5, lo=0, hi=5)
    cusum_h: float = opt(5.0, gt=0, hi=50)
    baseline_n: int = opt(16, lo=2, hi=1000)
    min_sigma_mm: float = opt(0.01, gt=0, hi=10)


@dataclass(frozen=True)
class SimLineSection(Section):
    """The simulated line of `rvis run --sim` (fakes/line.py): time scale, clamp cycle, the
    cell's warm-up and a knock of the sensor mount (knock_at_s < 0: none)."""

    name = "simline"
    scale: float = opt(60.0, gt=0, hi=10000)
    period_s: float = opt(60.0, gt=0, hi=86400)
    window_s: float = opt(20.0, gt=0, hi=86400)
    beat_s: float = opt(0.5, gt=0, hi=60)
    warmup_k: float = opt(8.0, lo=-50, hi=50)
    warmup_tau_s: float = opt(3600.0, gt=0, hi=1e6)
    warmup_start_s: float = opt(0.0, lo=0, hi=1e6)
    knock_at_s: float = opt(-1.0, lo=-1, hi=1e7)
    knock_mm: float = opt(0.3, lo=0, hi=100)
    knock_deg: float = opt(0.05, lo=0, hi=90)
    n_validation: int = opt(100, lo=1, hi=10000)


@dataclass(frozen=True)
class OpcUaSection(Section):
    """The service's OPC UA server (DESIGN.md section 8, docs/opcua.md): off by default, on
    loopback by default; any other endpoint needs a signing-and-encrypting security_policy
    ("none": no security, loopback only). Identification of the cell as OPC 40001-1 reads it
    ("" : derived, see docs/opcua.md)."""

    name = "opcua"
    enabled: bool = opt(False)
    endpoint: str = opt("opc.tcp://127.0.0.1:4840/rvis")
    security_policy: str = opt("none", choices=SECURITY_POLICIES)
    allow_anonymous: bool = opt(False)  # beyond loopback (on loopback anonymous is allowed)
    allow_ack: bool = opt(False)
    machine_name: str = opt("rvis-cell")
    manufacturer: str = opt("rvis")
    model: str = opt("RVIS in-line self-calibration, FANUC M-710iC/50 + laser-line sensor")
    serial_number: str = opt("")
    product_instance_uri: str = opt("")


@dataclass(frozen=True)
class CameraSection(Section):
    """The camera's acquisition for the sweeps of `rvis run` (full frames, software trigger);
    `rvis commission` chooses the exposure from its stripe check and writes it here."""

    name = "camera"
    exposure_us: float = opt(10000.0, gt=0, hi=1e6)
    gain_db: float = opt(0.0, lo=0, hi=48)

    def settings(self) -> Any:
        """The drivers.camera.CameraSettings of this section."""
        from drivers.camera import CameraSettings

        return CameraSettings(exposure_us=self.exposure_us, gain_db=self.gain_db)


@dataclass(frozen=True)
class CommissionSection(Section):
    """`rvis commission` (docs/commissioning.md): the speed of its motions (the guard refuses
    more) and the limit each step is checked against before the next one may start."""

    name = "commission"
    speed_pct: float = opt(10.0, gt=0, hi=100)
    exposures_us: Vec = opt([2500.0, 5000.0, 10000.0, 20000.0, 40000.0], gt=0, hi=1e6)
    min_stripe_rows: int = opt(60, lo=1, hi=100000)
    max_saturated_fraction: float = opt(0.02, lo=0, hi=1)
    min_peak_fraction: float = opt(0.15, gt=0, hi=1)
    max_peak_fraction: float = opt(0.9, gt=0, hi=1)
    max_stripe_width_px: float = opt(3.5, gt=0, hi=100)
    min_roi_margin_px: int = opt(8, lo=0, hi=10000)
    chessboards: int = opt(12, lo=3, hi=100)
    flat_targets: int = opt(4, lo=2, hi=50)
    max_reprojection_px: float = opt(0.1, gt=0, hi=10)
    max_plane_rms_mm: float = opt(0.03, gt=0, hi=10)
    max_target_rms_mm: float = opt(0.05, gt=0, hi=10)
    max_sphere_offset_mm: float = opt(50.0, gt=0, hi=1e4)
    max_rejected_fraction: float = opt(0.1, lo=0, hi=1)
    validation_views: int = opt(3, lo=1, hi=100)
    max_validation_rmse_mm: float = opt(0.2, gt=0, hi=100)
    seed: int = opt(0, lo=0, hi=2**32 - 1)


SECTIONS: tuple[type[Section], ...] = (
    RobotSection,
    FramesSection,
    BasePlateSection,
    SensorSection,
    SpheresSection,
    SimulationSection,
    CalibrationSection,
    PlanningSection,
    DevicesSection,
    ServiceSection,
    LineSection,
    SweepSection,
    DriftSection,
    SimLineSection,
    OpcUaSection,
    CameraSection,
    CommissionSection,
)
BY_NAME = {s.name: s for s in SECTIONS}


def _defaults() -> dict[str, dict[str, Any]]:
    return {s.name: dict(s()) for s in SECTIONS}


#: The embedded default cell, section -> key -> value (README: any key may be overridden).
DEFAULTS = _defaults()


@dataclass(frozen=True)
class CellConfig:
    """The resolved cell: nominal frames, limits, spheres (part frame) and every section."""

    T_part_base: F64
    T_flange_sensor: F64
    limits: nominal_robot.JointLimits
    spheres_part_mm: dict[str, F64]
    robot: RobotSection
    frames: FramesSection
    base_plate: BasePlateSection
    sensor: SensorSection
    spheres: SpheresSection
    simulation: SimulationSection
    calibration: CalibrationSection
    planning: PlanningSection
    devices: DevicesSection
    service: ServiceSection
    line: LineSection
    sweep: SweepSection
    drift: DriftSection
    simline: SimLineSection
    opcua: OpcUaSection
    camera: CameraSection
    commission: CommissionSection
    source: str = "<embedded default>"

    @property
    def base_plate_mm(self) -> tuple[float, float, float, float]:
        b = self.base_plate
        return (b.x_min_mm, b.x_max_mm, b.y_min_mm, b.y_max_mm)

    def model(self) -> Any:
        """The nominal rigid system model of this cell (calib.model.SystemModel): planning,
        simulation and the service use it."""
        from calib.model import SystemModel

        return SystemModel(self.T_part_base, self.T_flange_sensor, self.limits)

    def identification_model(self) -> Any:
        """The model `rvis identify` fits: rigid, or compliant ([calibration] model) with the
        section's payload and thermal settings (calib.compliance)."""
        from calib.compliance import CompliantSettings, select_model

        c = self.calibration
        settings = CompliantSettings(
            payload_kg=c.payload_kg,
            nominal_compliance_rad_per_nm=c.nominal_compliance_rad_per_nm,
            expansion_per_k=c.expansion_per_k,
            identify_expansion=c.identify_expansion,
            min_temp_span_k=c.min_temp_span_k,
            reference_temp_c=c.reference_temp_c,
        )
        return select_model(c.model, self.model(), settings)


def load_cell(path: str | Path | None = None) -> CellConfig:
    """The embedded default cell, overridden by the TOML file at `path` if given."""
    from app.config.check import SectionReader
    from app.config.tomlfile import key_lines, read_toml

    if path is None:
        return _resolve({s.name: s() for s in SECTIONS}, "<embedded default>")
    doc, text = read_toml(path)
    reader = SectionReader(str(path), key_lines(text))
    sections: dict[str, Section] = {}
    for name in doc:
        if name not in BY_NAME or not isinstance(doc[name], dict):
            raise reader.unknown_section(name, tuple(BY_NAME))
    for cls in SECTIONS:
        sections[cls.name] = reader.section(cls, doc.get(cls.name, {}))
    return _resolve(sections, str(path), reader)


def _resolve(s: dict[str, Section], source: str, reader: Any = None) -> CellConfig:
    from calib.transforms import apply, pose, rotvec_to_matrix

    def fail(section: str, key: str, reason: str) -> InputError:
        if reader is None:
            return InputError(f"[{section}] {key}: {reason}", file=source)
        return reader.fail(section, key, reason)

    rb, fr = s["robot"], s["frames"]
    assert isinstance(rb, RobotSection) and isinstance(fr, FramesSection)
    lower, upper = np.array(rb.joint_lower_deg), np.array(rb.joint_upper_deg)
    if np.any(lower >= upper):
        raise fail("robot", "joint_upper_deg", "every upper limit must exceed its lower limit")
    plate = s["base_plate"]
    if plate["x_min_mm"] >= plate["x_max_mm"] or plate["y_min_mm"] >= plate["y_max_mm"]:
        raise fail("base_plate", "x_max_mm", "expected x_min < x_max and y_min < y_max")
    if s["line"]["plc_temp_min_c"] >= s["line"]["plc_temp_max_c"]:
        raise fail("line", "plc_temp_max_c", "must exceed plc_temp_min_c")
    if s["simline"]["window_s"] >= s["simline"]["period_s"]:
        raise fail("simline", "window_s", "the clamp window must be shorter than period_s")
    if s["service"]["schedule"] == "adaptive" and s["service"]["estimator"] != "sequential":
        raise fail("service", "schedule", 'adaptive scheduling needs estimator = "sequential"')
    box = s["planning"]["workspace_mm"]
    if box[0] >= box[1] or box[2] >= box[3]:
        raise fail("planning", "workspace_mm", "expected [x_min, x_max, y_min, y_max], min < max")
    ua = s["opcua"]
    if ua["enabled"]:
        reason = endpoint_problem(ua["endpoint"], ua["security_policy"])
        if reason:
            raise fail("opcua", "endpoint", reason)
    sp = s["spheres"]
    if not sp["positions_mm"]:
        raise fail("spheres", "positions_mm", "expected a table of sphere ids -> [x, y, z]")
    devices = s["devices"]
    assert isinstance(devices, DevicesSection)
    for family, url in devices.urls().items():
        reason = _url_problem(family, url)
        if reason:
            raise fail("devices", family, reason)
    T_pb = pose(rotvec_to_matrix(np.radians(fr.part_base_rotvec_deg)), fr.part_base_xyz_mm)
    T_fs = pose(rotvec_to_matrix(np.radians(fr.flange_sensor_rotvec_deg)), fr.flange_sensor_xyz_mm)
    spheres = {
        tid: apply(T_pb, np.array(p)) if sp["frame"] == "base" else np.array(p, dtype=float)
        for tid, p in sp["positions_mm"].items()
    }
    return CellConfig(
        T_part_base=T_pb,
        T_flange_sensor=T_fs,
        limits=nominal_robot.JointLimits(lower, upper),
        spheres_part_mm=spheres,
        source=source,
        **s,  # type: ignore[arg-type]
    )


def _url_problem(family: str, url: str) -> str:
    """Why `url` cannot select a `family` backend ("" when it can); imports no backend."""
    from drivers.errors import DeviceConfigError
    from drivers.registry import BACKENDS
    from drivers.url import parse_url
    from fakes.wiring import register_fakes

    register_fakes()  # a cell's fake:// devices are the simulated cell's
    try:
        parsed = parse_url(url)
        scheme = parsed.scheme
        parsed.flag("trace")
    except DeviceConfigError as exc:
        return str(exc)
    if scheme not in BACKENDS[family]:
        known = ", ".join(f"{k}://" for k in BACKENDS[family])
        return f"no {family} backend for {scheme}:// (known: {known})"
    return ""
