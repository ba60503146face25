"""The cell's devices: their URLs (`[devices]`, drivers.registry), the camera's acquisition
(`[camera]`) and the commissioning's limits (`[commission]`)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from app.config.section import Section, opt

Vec = tuple[float, ...]


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

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        for family, url in self.urls().items():
            reason = url_problem(family, url)
            if reason:
                yield family, reason


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
    # the calibration step: `model` "service" identifies the model the service runs
    # (CellConfig.commissioning_model: its first version is the estimator's prior),
    # "calibration" [calibration] model (the paper's rigid 30); calibration_views_per_sphere
    # > 0: the pre-calibration's random views taken with the plan's up to that many a sphere
    # (0: the plan's alone; the pre-calibration measures at least the plan's count). A new
    # cell's first hour runs on them: 18 views a sphere left it 1.13-1.52x the robot's floor
    # on judging seeds 301-324 (7 of 12 over 1.3), 36 views 1.08-1.28x (the rigid model
    # 1.6-1.8x whatever the count: docs/results/estimator.md, "The first hour: 36 views").
    # The paper's commissioning is `model = "calibration"` with 0
    model: str = opt("service", choices=("calibration", "service"))
    calibration_views_per_sphere: int = opt(36, lo=0, hi=1000)
    validation_views: int = opt(3, lo=1, hi=100)
    max_validation_rmse_mm: float = opt(0.2, gt=0, hi=100)
    # the paper's validation (section 4, eq. 19): a sphere on a tracker nest at this many
    # workspace positions, each measured by the tracker (target `validation_target`) and by
    # rvis from a view the calibration did not use; its RMS error held to max_workspace_rmse_mm.
    # Its errors bound the unmodelled term of every statement the in-line service makes (the
    # upper 95 % bound of their sigma, calib.uncertainty.sigma_upper_mm; app.line.estimate):
    # 50 positions bound sigma within 1.11x, 20 within 1.18x
    # (docs/results/accuracy-first-window.md weighs the 30 more tracker positions)
    workspace_positions: int = opt(20, lo=3, hi=1000)
    # `rvis maintain` (app/maintain/): the same validation at fewer positions, each measured
    # from maintenance_workspace_views views (the first from home, the others a short motion
    # away: each view a stop of its own, with its own share of the robot's repeatability);
    # 8 x 3 errors know the RMS to about +-15 % at 95 % where 10 positions from one view each
    # knew it to +-25 %, at about the same robot time (a procedure a third of a
    # commissioning's); and the plan's views per sphere the changed group is identified on
    maintenance_positions: int = opt(8, lo=3, hi=1000)
    maintenance_workspace_views: int = opt(3, lo=1, hi=20)
    maintenance_views_per_sphere: int = opt(2, lo=1, hi=100)
    # a replaced sensor's mount: this many views more, dealt to those in turn, each a short
    # motion from its view, that see the sphere elsewhere in the field of view (the mount's
    # tilt and shift told apart): measured on seeds 32 and 35, 2 views per sphere and 16 of
    # these left the truth 1.10x the unchanged cell's in 342-347 s of robot time, 3 and 12
    # 1.07x in 365-369 s (over a third of a commissioning's), 3 and none 1.23x on seed 35
    maintenance_fov_views: int = opt(16, lo=0, hi=100)
    validation_target: str = opt("VAL")
    max_workspace_rmse_mm: float = opt(0.2, gt=0, hi=100)
    # the plant's tolerance T of the body features measured, its full range (+-0.5 mm is 1.0;
    # 0: not given): the report states VDA 5's capability ratio 2 U95 / T of the commissioned
    # cell (at most 30 %; a T the cell's U95 fails is questioned as a possible half-range), and
    # the state directory's [service] accuracy_limit_mm becomes 0.15 T (U95 at 30 % of T; T = 1
    # mm when not given), or 1.5x the cell's own U95 when that is higher
    # (calib.uncertainty.accuracy_limit_mm)
    tolerance_mm: float = opt(0.0, lo=0, hi=1000)
    seed: int = opt(0, lo=0, hi=2**32 - 1)


def url_problem(family: str, url: str) -> str:
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


@dataclass(frozen=True)
class ResultsSection(Section):
    """The bodies' results as the plant's SPC system reads them (AQDEF, docs/inspection.md):
    the station written as the machine's number and description (K1081, K1082), the folder
    the service writes each body's file into, and how long the bodies are kept."""

    name = "results"
    station: str = opt("rvis")
    station_description: str = opt("rvis in-line inspection cell")
    # the folder the plant's SPC import watches: the service writes a `.dfq` file a body there
    # (app/line/body_export.py); "" none; a relative path is under the state directory
    dir: str = opt("")
    # the bodies (their evaluations, values and raw data) older than this many days are deleted
    # by the service's retention pass, with the files it wrote of them into `dir`; 0 keeps them.
    # A body stays while an open suspect interval holds it or a file of it waits to be written
    keep_days: float = opt(365.0, lo=0, hi=36500)
