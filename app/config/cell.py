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
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.config.devices import CameraSection, CommissionSection, DevicesSection, ResultsSection
from app.config.line import (
    DriftSettings,
    LineSettings,
    OpcUaSettings,
    ServiceSection,
    SimLineSection,
    SweepSettings,
)
from app.config.section import Section, opt
from app.errors import InputError
from calib import datasheet
from calib.compliance_settings import RANGES as _R
from calib.compliance_settings import CompliantSettings
from calib.gate_limits import OFFLINE, Gates

if TYPE_CHECKING:  # the sections load no numerics: a command that reads only its settings
    import numpy as np  # (`rvis status`) starts fast; the geometry is resolved by load_cell
    from numpy.typing import NDArray

    from calib.robot import JointLimits

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


@dataclass(frozen=True)
class RobotSection(Section):
    name = "robot"
    model: str = opt("fanuc-m710ic50", choices=ROBOT_MODELS)
    joint_lower_deg: Vec = opt(list(datasheet.JOINT_LOWER_DEG), lo=-720, hi=720, n=6)
    joint_upper_deg: Vec = opt(list(datasheet.JOINT_UPPER_DEG), lo=-720, hi=720, n=6)
    # the data sheet's ISO 9283 pose repeatability RP: the uncertainty of a reference that the
    # robot's own motion provides (the sensor acceptance's SD)
    repeatability_mm: float = opt(datasheet.POSE_REPEATABILITY_MM, lo=0, hi=10)


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
    # one coordinate's sd of a sphere centre from one sweep with the robot standing (the
    # sensor's own share of a measurement's noise; the estimator adds the robot's RP through
    # the model: [service] jump_sigma_mm)
    centre_sd_mm: float = opt(0.005, lo=0, hi=1)
    # the type-B standard uncertainty per side [mm] of what stays systematic in where the
    # sensor puts a round hole's edge (edge_u_mm) and a slot's (edge_u_slot_mm: its straight
    # sides and end arcs), which a size's U95 carries (app/inspect/values.py): from the
    # sensor's acceptance on certified bores and slots (bench/edge.py measures the simulated
    # sensor's); 0.002, a tenth of a row step as a uniform bound, when not measured
    edge_u_mm: float = opt(0.002, lo=0, hi=1)
    edge_u_slot_mm: float = opt(0.002, lo=0, hi=1)
    # the acceptance test (VDI/VDE 2634-2, vision/acceptance.py): the largest magnitudes of the
    # probing errors form PF and size PS and of the sphere-spacing error SD [mm]; the in-line
    # chart of PS (app/line/sensor_watch.py) raises the `sensor` alarm beyond max_ps_mm. PF, the
    # guideline's range over ~1e4 points (0.3 % left out), is 7-9.5 times the per-point noise
    # sigma: 0.15 mm holds a sensor of up to 16-20 um per point (the simulated one 11-16 um,
    # its PF 0.10-0.115 mm), not one at the speckle floor's upper end (docs/results/
    # pf-guideline.md)
    max_pf_mm: float = opt(0.15, gt=0, hi=10)
    max_ps_mm: float = opt(0.025, gt=0, hi=10)
    max_sd_mm: float = opt(0.015, gt=0, hi=10)


@dataclass(frozen=True)
class SpheresSection(Section):
    name = "spheres"
    frame: str = opt("base", choices=("base", "part"))
    positions_mm: dict[str, Vec] = opt(PAPER_TABLE1_BASE_MM, lo=-1e5, hi=1e5, n=3)


@dataclass(frozen=True)
class SimulationSection(Section):
    name = "simulation"
    seed: int = opt(0, lo=0, hi=2**32 - 1)
    # how a simulated commissioning measured (`rvis commission --sim --geometric`): `rvis run
    # --sim` on its directory measures the same way unless told
    geometric: bool = opt(False)
    tracker_noise_mm: float = opt(0.01, lo=0, hi=10)
    # the defaults of these two are fakes.cell_spec.SimSettings' (its docstring says why; a test
    # pins them equal): the geometric sensor's own noise, the robot's ISO 9283 RP (0: exact)
    sensor_noise_mm: float = opt(0.005, lo=0, hi=10)
    repeatability_mm: float = opt(0.07, lo=0, hi=10)
    compliance: bool = opt(True)
    thermal: bool = opt(True)
    temp_c: float = opt(20.0, lo=-40, hi=80)


_OFF = OFFLINE
_CS_DEFAULT = CompliantSettings()


def _deg(rad: float | None) -> float:
    assert rad is not None
    return math.degrees(rad)


def gates_of(section: Mapping[str, Any], base: Gates) -> Gates:
    """calib.gate_limits.Gates from the gate keys a section has (degrees at this boundary,
    radians in calib), the others from `base`: the one conversion of the cell file's gates."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(base):
        deg_key = f.name.removesuffix("_rad") + "_deg"
        if f.name.endswith("_rad") and deg_key in section:
            values[f.name] = math.radians(section[deg_key])
        elif f.name in section:
            values[f.name] = section[f.name]
    return dataclasses.replace(base, **values)


@dataclass(frozen=True)
class CalibrationSection(Section):
    """Identification and its quality gates (calib.gates): a result is used only when it
    converged, has rank 30, finite values, RMS <= max_rms_mm, condition <= max_condition and
    every parameter within the allowed change from its reference."""

    name = "calibration"
    model: str = opt("rigid", choices=("rigid", "compliant"))
    # the compliant model's settings: defaults and ranges are calib.compliance_settings'
    payload_kg: float = opt(_CS_DEFAULT.payload_kg, lo=_R["payload_kg"][0], hi=_R["payload_kg"][1])
    nominal_compliance_rad_per_nm: float = opt(
        _CS_DEFAULT.nominal_compliance_rad_per_nm,
        lo=_R["nominal_compliance_rad_per_nm"][0],
        hi=_R["nominal_compliance_rad_per_nm"][1],
    )
    expansion_per_k: float = opt(
        _CS_DEFAULT.expansion_per_k, lo=_R["expansion_per_k"][0], hi=_R["expansion_per_k"][1]
    )
    identify_expansion: bool = opt(_CS_DEFAULT.identify_expansion)
    min_temp_span_k: float = opt(
        _CS_DEFAULT.min_temp_span_k, gt=_R["min_temp_span_k"][0], hi=_R["min_temp_span_k"][1]
    )
    reference_temp_c: float = opt(
        _CS_DEFAULT.reference_temp_c, lo=_R["reference_temp_c"][0], hi=_R["reference_temp_c"][1]
    )
    configs_per_sphere: int = opt(6, lo=1, hi=1000)
    loss: str = opt("linear", choices=LOSSES)
    max_rms_mm: float = opt(_OFF.max_rms_mm, gt=0, hi=100)
    max_condition: float = opt(_OFF.max_condition, gt=1)
    max_joint_change_mm: float = opt(_OFF.max_joint_change_mm, gt=0, hi=1000)
    max_joint_change_deg: float = opt(_deg(_OFF.max_joint_change_rad), gt=0, hi=180)
    max_sensor_change_mm: float = opt(_OFF.max_sensor_change_mm, gt=0, hi=1000)
    max_sensor_change_deg: float = opt(_deg(_OFF.max_sensor_change_rad), gt=0, hi=180)

    def gates(self) -> Gates:
        """The calib.gate_limits.Gates of this section (OFFLINE with this file's values: the
        part->base pose unbounded)."""
        return gates_of(self, OFFLINE)


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
    patience: int = opt(3, lo=0, hi=10000)  # docs/results/plan-speed.md: 3 met <= 10 s
    stall_tolerance: float = opt(1e-3, lo=0, hi=1)
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
    LineSettings,
    SweepSettings,
    DriftSettings,
    SimLineSection,
    OpcUaSettings,
    CameraSection,
    CommissionSection,
    ResultsSection,
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
    limits: JointLimits
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
    line: LineSettings
    sweep: SweepSettings
    drift: DriftSettings
    simline: SimLineSection
    opcua: OpcUaSettings
    camera: CameraSection
    commission: CommissionSection
    results: ResultsSection
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
        """The model `rvis identify` and the plan fit: rigid, or compliant ([calibration]
        model) with the section's payload and thermal settings (calib.compliance)."""
        return self._model_of(self.calibration.model)

    def commissioning_model(self) -> Any:
        """The model the commissioning identifies ([commission] model): [calibration] model,
        or ("service") the one the in-line service runs, whose first version and estimator's
        prior its parameters are (compliant when either section says so)."""
        if self.commission.model == "calibration":
            return self.identification_model()
        kinds = (self.calibration.model, self.service.model)
        return self._model_of("compliant" if "compliant" in kinds else "rigid")

    def service_model(self) -> Any:
        """The model the in-line service identifies ([service] model), with [calibration]'s
        payload and thermal settings."""
        return self._model_of(self.service.model)

    def _model_of(self, kind: str) -> Any:
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
        return select_model(kind, self.model(), settings)


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
    calibration, service = doc.get("calibration", {}), doc.get("service", {})
    if "model" in calibration and "model" not in service:  # a file from before [service] model
        service_section: Any = sections["service"]
        sections["service"] = dataclasses.replace(service_section, model=calibration["model"])
    return _resolve(sections, str(path), reader)


def _resolve(s: dict[str, Section], source: str, reader: Any = None) -> CellConfig:
    import numpy as np

    from calib.robot import JointLimits
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
    box = s["planning"]["workspace_mm"]
    if box[0] >= box[1] or box[2] >= box[3]:
        raise fail("planning", "workspace_mm", "expected [x_min, x_max, y_min, y_max], min < max")
    sp = s["spheres"]
    if not sp["positions_mm"]:
        raise fail("spheres", "positions_mm", "expected a table of sphere ids -> [x, y, z]")
    T_pb = pose(rotvec_to_matrix(np.radians(fr.part_base_rotvec_deg)), fr.part_base_xyz_mm)
    T_fs = pose(rotvec_to_matrix(np.radians(fr.flange_sensor_rotvec_deg)), fr.flange_sensor_xyz_mm)
    spheres = {
        tid: apply(T_pb, np.array(p)) if sp["frame"] == "base" else np.array(p, dtype=float)
        for tid, p in sp["positions_mm"].items()
    }
    return CellConfig(
        T_part_base=T_pb,
        T_flange_sensor=T_fs,
        limits=JointLimits(lower, upper),
        spheres_part_mm=spheres,
        source=source,
        **s,  # type: ignore[arg-type]
    )
