"""The in-line service's settings, each declared once: the cell file's `[line]`, `[sweep]`,
`[drift]`, `[service]`, `[opcua]` and `[simline]` tables are these sections, and the service
uses them as they are (app.line.settings.from_cell gathers them).

`[service]` is one table in the file and three concerns in the code: how the service
recalibrates (`RecalibSettings`), the gates of an in-line identification (`InlineGateSettings`,
defaults from calib.gate_limits.INLINE) and its operations (`OperationsSettings`); `ServiceSection`
is the three together. Times are in the clock's seconds, angles at this boundary in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import ClassVar

from app.config.endpoint import SECURITY_POLICIES, endpoint_problem
from app.config.section import Section, opt
from app.state_defaults import DEFAULT_ROOT, MIN_FREE_MB
from calib import datasheet
from calib.gate_limits import INLINE

#: the simulated line's knock kinds (fakes.truth.KNOCK_KINDS, which tests check against)
SIM_KNOCK_KINDS = ("sensor", "fixture", "joint", "J1", "J2", "J3", "J4", "J5", "J6", "sphere")

Vec = tuple[float, ...]


@dataclass(frozen=True)
class LineSettings(Section):
    """The PLC handshake and the motion-time model of one window."""

    name = "line"
    poll_s: float = opt(0.01, gt=0, hi=10)
    heartbeat_timeout_s: float = opt(3.0, gt=0, hi=600)
    override_pct: int = opt(100, lo=1, hi=100)
    speed_pct: float = opt(100.0, gt=0, hi=100)
    joint_speed_deg_s: Vec = opt(list(datasheet.JOINT_SPEED_DEG_S), gt=0, hi=2000, n=6)
    accel_s: float = opt(0.4, lo=0, hi=60)  # per move: acceleration and deceleration allowance
    settle_s: float = opt(0.2, lo=0, hi=60)  # per move: settling at FINE
    home_deg: Vec = opt(list(datasheet.HOME_DEG), lo=-720, hi=720, n=6)
    home_tol_deg: float = opt(0.05, gt=0, hi=5)
    window_s: float = opt(8.0, gt=0, hi=3600)  # a clamp window (the PLC sends only the bit)
    # how long the PLC leaves a clamped body for its features once it raises body_ready (the
    # PLC sends only the bit): the body's route is cut where the next feature would not be
    # measured and the robot home by then (its features "not measured", the reason said)
    body_window_s: float = opt(38.0, gt=0, hi=3600)
    margin_s: float = opt(0.5, lo=0, hi=60)  # kept free at the end of every window
    slots_per_window: int = opt(1, lo=1, hi=100)
    # while a jump no single group explains waits for its full re-identification: up to this
    # many slots in a window (those that fit its time budget), a schedule cycle soon
    # (app/line/slot_choice.py)
    step_slots_per_window: int = opt(6, lo=1, hi=100)
    # the PLC writes the cell temperature in its word 2 (off: the word is not read; a PLC
    # program that predates it leaves 0 there, which is not 0 degC)
    plc_temperature: bool = opt(False)
    # a reading outside this range is "no temperature" with an alarm, never a number
    plc_temp_min_c: float = opt(5.0, lo=-40, hi=100)
    plc_temp_max_c: float = opt(50.0, lo=-40, hi=100)
    # the PLC holds the clamped body's identifier in its words 3-6, read at each window's rising
    # edge and stored with the window (the bodies of a suspect interval): "u32" a 32-bit body
    # number (words 3-4), "serial8" a serial of up to 8 characters (words 3-6), "none" off (the
    # words are not read: a PLC program without them may not have the registers at all)
    plc_body_id: str = opt("none", choices=("none", "u32", "serial8"))

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        if self.plc_temp_min_c >= self.plc_temp_max_c:
            yield "plc_temp_max_c", "must exceed plc_temp_min_c"


@dataclass(frozen=True)
class SweepSettings(Section):
    """The galvo sweep of one measurement: n_frames commands [V] evenly over +-span_v."""

    name = "sweep"
    n_frames: int = opt(24, lo=3, hi=1000)
    span_v: float = opt(3.2, gt=0, hi=10)
    frame_s: float = opt(0.05, gt=0, hi=10)  # set the galvo, settle, expose, transfer
    grab_timeout_s: float = opt(1.0, gt=0, hi=60)

    def commands_v(self) -> tuple[float, ...]:
        import numpy as np  # not at import: reading the settings loads no numerics

        return tuple(float(v) for v in np.linspace(-self.span_v, self.span_v, self.n_frames))

    @property
    def duration_s(self) -> float:
        return self.n_frames * self.frame_s


#: why a key an older rvis read is no longer read (accepted with a warning: app.config.check)
CHARTS_RETIRED = "the drift charts, replaced by the one estimator: docs/estimator.md"


@dataclass(frozen=True)
class DriftSettings(Section):
    """The chart of the sensor's own PS (app/line/sensor_watch.py, REFERENCE.md): EWMA
    (lambda) and upper CUSUM (decision h, in sigmas), sigma learned from its first baseline_n
    measurements."""

    name = "drift"
    retired: ClassVar[dict[str, str]] = {
        k: CHARTS_RETIRED for k in ("ewma_l", "cusum_k", "min_sigma_mm")
    }
    ewma_lambda: float = opt(0.2, gt=0, hi=1)
    # the CUSUM's decision interval [sigma] and the measurements its baseline (mean, sigma) is
    # learned from: with its slack of 0.5 sigma and known parameters, the two-sided chart's
    # in-control run length is about exp(h + 1.166) - h - 2.166 measurements (Siegmund): 7e4
    # with 10, 470 with 5; a baseline learned from few values shortens it far more (its mean
    # and sigma are off by a fraction of sigma for good: 50 in-control 8 h shifts at one
    # sphere a minute, 480 values each, raised a false alarm in 41 with h 5 and 16 values, 13
    # with 10 and 16, none with 10 and 100; tests/sim/test_sensor_watch.py). 100 values cover
    # every view of a schedule four times (PS differs by a few um from view to view); a shift
    # of 1 sigma is then signalled after about 15 measurements. Until the baseline is learned
    # (1.7 h at one sphere a minute) the EWMA against the acceptance limit watches alone.
    cusum_h: float = opt(10.0, gt=0, hi=50)
    baseline_n: int = opt(100, lo=2, hi=1000)


#: the rolling set's size by the model identified ([service] rolling_size = 0): about 5
#: equations per parameter for the compliant model (43), the paper's 24 for the rigid one (30)
ROLLING_SIZE = {"rigid": 24, "compliant": 72}


@dataclass(frozen=True)
class RecalibSettings(Section):
    """When and how the service recalibrates (part of `[service]`)."""

    name = "service"
    mode: str = opt("auto", choices=("auto", "approve"))
    # measurements a recalibration identifies from; 0: by the model identified (ROLLING_SIZE:
    # the paper's 24 for rigid, 72 for compliant, whose 43 parameters fit 24 measurements to
    # 0.019-0.031 mm while predicting held-out ones to 0.024-0.063 mm; measured on 8 h shifts:
    # docs/results/accuracy-first-window.md)
    rolling_size: int = opt(0, lo=0, hi=100000)
    holdout_size: int = opt(4, lo=1, hi=1000)
    every_n: int = opt(24, lo=1, hi=100000)  # new measurements between recalibrations
    # a recalibration's candidate: "posterior", the one estimator's posterior (the version in
    # force its prior, every measurement since folded in: docs/estimator.md), the rolling set's
    # identification only while a jump is in hand; "rolling", the rolling set identified alone
    # (each recalibration then forgets what came before it). The posterior needs the
    # commissioning of the service's model ([commission] model, the default): on a rigid
    # commissioning's prior it made a shift worse (docs/results/estimator.md, "The
    # commissioning and the posterior")
    candidate: str = opt("posterior", choices=("rolling", "posterior"))
    max_nfev: int = opt(200, lo=10, hi=10000)
    # the plant's limit for the U95 of a point measured now: a window whose U95 is above it is
    # in a suspect interval. 0: by calib.uncertainty.accuracy_limit_mm, VDA 5's 2U/T <= 30 % for
    # a body tolerance of +-0.5 mm (0.15 mm), or 1.5x the cell's own U95 from its commissioning's
    # workspace validation when that is higher (a healthy cell is not at its limit); `rvis
    # commission` writes it from the plant's tolerance ([commission] tolerance_mm) the same way
    accuracy_limit_mm: float = opt(0.0, lo=0, hi=100)
    # the model the service identifies: "compliant" (J2/J3 gravity deflection and the thermal
    # term, with [calibration]'s payload and thermal settings) or "rigid" (the paper's). A
    # version in force of a rigid model (a rigid commissioning) is carried into the compliant
    # model at start. A cell file that sets [calibration] model and not this key keeps its
    # service on that model (load_cell). The default by the knock campaign (issue 28,
    # docs/results/shift-knocks/configurations.md): compliant + batch measured every body
    # better than rigid + batch and kept the worst window after a knock's correction lowest
    model: str = opt("compliant", choices=("rigid", "compliant"))
    # "batch": identification on the rolling set; "sequential": app.line.inline_seq
    estimator: str = opt("batch", choices=("batch", "sequential"))
    seq_apply_every: int = opt(8, lo=1, hi=100000)  # accepted updates between two candidates
    seq_measurement_std_mm: float = opt(0.025, gt=0, hi=10)
    seq_drift_mm: float = opt(0.002, lo=0, hi=10)  # random-walk standard deviation per update
    seq_drift_rad: float = opt(2e-6, lo=0, hi=0.1)
    seq_drift_extra: float = opt(0.0, lo=0, hi=1)
    seq_knock_mm: float = opt(0.5, lo=0, hi=100)  # added to the std when a step is flagged
    seq_knock_rad: float = opt(1e-3, lo=0, hi=1)
    # the prior of a parameter the version in force has no covariance for (a nominal or an
    # imported version): the sequential estimator's and the jump test's (app/line/jumps.py)
    seq_prior_mm: float = opt(0.5, gt=0, hi=100)
    seq_prior_rad: float = opt(1e-3, gt=0, hi=1)
    # "cycle": the plan's configurations in turn; "adaptive" (sequential only): the most
    # informative configuration that fits the window
    schedule: str = opt("cycle", choices=("cycle", "adaptive"))
    # a jump's correction is applied once its predicted uncertainty over the measuring volume
    # at the schedule's configurations (per coordinate) is at most this, or at most half the
    # jump it corrects (app/line/jumps.py); the rest is refined as measurements come
    step_max_std_mm: float = opt(0.035, gt=0, hi=10)
    # a step seen larger than this at the measured spheres is beyond a knock (a sensor
    # replaced, an axis remastered, a fixture renewed): the cell holds in FAULT with the
    # `maintenance` alarm and asks for the procedure that fits (app/line/beyond_knock.py);
    # knocks the fast correction is for move the spheres by up to about 1 mm
    maintenance_step_mm: float = opt(1.5, gt=0, hi=1000)

    # one coordinate of a sphere centre's own noise: the sensor's and the robot's repeatability;
    # 0 (the default): derived at the service's start, [sensor] centre_sd_mm and [robot]
    # repeatability_mm through the model at the schedule's views (app.line.estimate)
    jump_sigma_mm: float = opt(0.0, lo=0, hi=10)
    # the unmodelled term's floor without a commissioning's workspace validation (one coordinate)
    jump_unmodelled_mm: float = opt(0.03, lo=0, hi=10)
    # slow drift as a random walk of the parameters, per sqrt(hour)
    jump_drift_mm_per_h: float = opt(0.02, lo=0, hi=10)
    jump_drift_rad_per_h: float = opt(1e-5, lo=0, hi=0.1)
    jump_window: int = opt(36, lo=4, hi=1000)  # measurements the jump test looks at
    # the rate of a jump detected per measurement when nothing jumped (Bonferroni over the
    # groups and onsets tested: an upper bound); an 8 h shift tests about 480 measurements, so
    # 1e-5 bounds a shift's false alarm at 0.5 % (1e-4: 5 %, one in 20 shifts)
    jump_false_alarm: float = opt(1e-5, gt=0, hi=0.1)
    # measurements after the onset with no decisive group: a full recalibration instead
    jump_settle: int = opt(6, lo=1, hi=1000)
    # measurements on the corrected version without a jump (and the cell vouching) that end the
    # episode: its interval then ends when the correction came into force
    jump_confirm: int = opt(1, lo=1, hi=1000)
    # windows in a row the cell cannot vouch for its U95 within accuracy_limit_mm: the
    # `accuracy` alarm, and a full recalibration unless a jump's episode is handling it
    accuracy_alarm_windows: int = opt(3, lo=1, hi=100000)

    @property
    def rolling_n(self) -> int:
        """The rolling set's size in force: `rolling_size`, or the model's (0)."""
        return self.rolling_size or ROLLING_SIZE[self.model]

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        if 0 < self.rolling_size < 10:
            yield "rolling_size", "0 (by the model) or at least 10"
        if self.schedule == "adaptive" and self.estimator != "sequential":
            yield "schedule", 'adaptive scheduling needs estimator = "sequential"'


def _deg(rad: float | None) -> float:
    assert rad is not None
    return math.degrees(rad)


_IN = INLINE


@dataclass(frozen=True)
class InlineGateSettings(Section):
    """The gates of an in-line identification (part of `[service]`; calib.gate_limits.INLINE): the
    change from the parameters in force, bounded per chain piece, and the candidate's RMS on
    held-out measurements at most max_holdout_ratio times that of the parameters in force. RMS
    and condition limits are [calibration]'s."""

    name = "service"
    max_joint_change_mm: float = opt(_IN.max_joint_change_mm, gt=0, hi=1000)
    max_joint_change_deg: float = opt(_deg(_IN.max_joint_change_rad), gt=0, hi=180)
    max_sensor_change_mm: float = opt(_IN.max_sensor_change_mm, gt=0, hi=1000)
    max_sensor_change_deg: float = opt(_deg(_IN.max_sensor_change_rad), gt=0, hi=180)
    max_base_change_mm: float = opt(_IN.max_base_change_mm, gt=0, hi=1000)
    max_base_change_deg: float = opt(_deg(_IN.max_base_change_rad), gt=0, hi=180)
    max_holdout_ratio: float = opt(_IN.max_holdout_ratio, gt=0, hi=10)


@dataclass(frozen=True)
class OperationsSettings(Section):
    """Where the service keeps its state and how it keeps it (part of `[service]`;
    docs/operations.md): the state directory, its operators' group ("": none, 0750), the
    engineers' group (who may approve, reject, roll back, reset, shelve; "": everyone who can
    connect, app/line/roles.py), the free
    space below which a warning alarm is raised, the raw sweeps kept, and how long events and
    the documents of rejected calibrations are kept (0: for ever)."""

    name = "service"
    state_dir: str = opt(DEFAULT_ROOT)
    operators_group: str = opt("")
    engineers_group: str = opt("")
    min_free_mb: float = opt(MIN_FREE_MB, lo=0, hi=1e7)
    raw_sweeps_keep: int = opt(0, lo=0, hi=100000)
    events_keep_days: float = opt(90.0, lo=0, hi=36500)
    rejected_keep_days: float = opt(30.0, lo=0, hi=36500)


@dataclass(frozen=True)
class ServiceSection(OperationsSettings, InlineGateSettings, RecalibSettings):
    """The in-line service (`rvis run`): the cell file's `[service]` table, the three settings
    above in one (each consumer takes its part with app.config.section.project)."""

    name = "service"
    retired: ClassVar[dict[str, str]] = {
        k: CHARTS_RETIRED
        for k in (
            "detector",
            "step_correction",
            "step_min_measurements",
            "step_min_margin",
            "step_std_fraction",
            "step_min_mm",
            "step_refine_mm",
            "recovery_confidence",
            "recovery_min_measurements",
            "recovery_margin",
            "recovery_tolerance_mm",
            "seq_max_std_mm",
        )
    }

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        yield from RecalibSettings.cross_checks(self)


@dataclass(frozen=True)
class OpcUaSettings(Section):
    """The service's OPC UA server (DESIGN.md section 8, docs/opcua.md): off by default, on
    loopback by default; any other endpoint needs a signing-and-encrypting security_policy
    ("none": no security, loopback only). Identification of the cell as OPC 40001-1 reads it
    ("" : derived, see docs/opcua.md)."""

    name = "opcua"
    enabled: bool = opt(False)
    endpoint: str = opt("opc.tcp://127.0.0.1:4840/rvis")
    security_policy: str = opt("none", choices=SECURITY_POLICIES)
    allow_anonymous: bool = opt(False)  # beyond loopback (on loopback anonymous is allowed)
    allow_ack: bool = opt(False)  # acknowledging alarms from OPC UA (audited)
    machine_name: str = opt("rvis-cell")
    manufacturer: str = opt("rvis")
    model: str = opt("RVIS in-line self-calibration, FANUC M-710iC/50 + laser-line sensor")
    serial_number: str = opt("")  # "": the host's name
    product_instance_uri: str = opt("")  # "": urn:<manufacturer>:<serial number>:<machine>

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        if self.enabled:
            reason = endpoint_problem(self.endpoint, self.security_policy)
            if reason:
                yield "endpoint", reason


@dataclass(frozen=True)
class SimLineSection(Section):
    """The simulated line of `rvis run --sim` (fakes/line.py): its time, clamp cycle, the
    cell's warm-up and a knock (knock_at_s < 0: none) of the sensor mount (knock_kind sensor:
    knock_mm shift and knock_deg tilt), of the spheres' frame (fixture: the same about the
    spheres' centroid), of an encoder zero (J1 .. J6, joint = J2: a slip of knock_deg) or of
    one sphere alone (sphere: a move of knock_mm), and a maintenance event beyond a knock
    (maintenance_at_s < 0: none; issue 41).

    Time on the simulated line is virtual: it passes by the simulated durations of what
    happens (motions, exposures and read-outs, the DAC's settling, the service's own waits,
    an identification's modelled cost), so a seed and these settings give one outcome. `scale`
    paces it at that many sim seconds per real second for a person who watches (`rvis tui
    --sim`, `rvis run --sim` without --windows, `--scale`); otherwise it runs as fast as the
    CPU. `rvis devices sim` runs the same line's devices as their own process on the wall
    clock (its own `--scale`, default 1; `scale`, `poll_s`, `identification_s`,
    `camera_readout_s` and `galvo_settle_s` are the virtual clock's and unused there)."""

    name = "simline"
    scale: float = opt(60.0, gt=0, hi=10000)
    period_s: float = opt(60.0, gt=0, hi=86400)
    window_s: float = opt(20.0, gt=0, hi=86400)
    # the simulated PLC's body phase: body_ready raised 1 s into each period for body_s,
    # ending 1 s before the window (-1: all that time, period_s - window_s - 2; 0: off); the
    # service gets it as its [line] body_window_s
    body_s: float = opt(-1.0, lo=-1, hi=86400)
    beat_s: float = opt(0.5, gt=0, hi=60)
    # the service's PLC poll on the simulated line (in place of [line] poll_s): every poll is a
    # real exchange over loopback, so this sets how fast an unpaced run goes; a window's rising
    # edge is seen up to this late, which the window's margin takes in
    poll_s: float = opt(1.0, gt=0, hi=60)
    # the modelled cost of one in-line identification (the worker's compute): its outcome is
    # seen this long after it was submitted, however fast the machine computed it (one
    # identification of the rolling set computes in 20-75 ms on the 2-core development machine:
    # 2 s leaves room for a slower cell PC and the hand-over to the worker)
    identification_s: float = opt(2.0, lo=0, hi=3600)
    camera_readout_s: float = opt(0.033, lo=0, hi=10)  # per frame, after its exposure
    galvo_settle_s: float = opt(0.002, lo=0, hi=10)  # per galvo command
    warmup_k: float = opt(8.0, lo=-50, hi=50)
    warmup_tau_s: float = opt(3600.0, gt=0, hi=1e6)
    warmup_start_s: float = opt(0.0, lo=0, hi=1e6)
    knock_at_s: float = opt(-1.0, lo=-1, hi=1e7)
    knock_mm: float = opt(0.3, lo=0, hi=100)
    knock_deg: float = opt(0.05, lo=0, hi=90)
    knock_kind: str = opt("sensor", choices=SIM_KNOCK_KINDS)
    # a maintenance event at world time maintenance_at_s (< 0: none), beyond a knock
    # (fakes.truth.Maintenance): a sensor replaced, the motor or encoder of maintenance_axis
    # replaced, the sphere fixture renewed (maintenance_sphere: only that sphere replaced;
    # maintenance_frame: the renewal moves the part frame against the robot's base, the
    # spheres keeping their places in it); maintenance_mm and maintenance_deg its size (0:
    # drawn from the seed within the kind's)
    maintenance_at_s: float = opt(-1.0, lo=-1, hi=1e7)
    maintenance_kind: str = opt("sensor", choices=("sensor", "axis", "fixture"))
    maintenance_axis: int = opt(2, lo=1, hi=6)
    maintenance_sphere: str = opt("")
    maintenance_frame: bool = opt(False)
    maintenance_mm: float = opt(0.0, lo=0, hi=100)
    maintenance_deg: float = opt(0.0, lo=0, hi=10)
    n_validation: int = opt(100, lo=1, hi=10000)
    # a process shift at the body shop (a fixture or a tool change): from the world's body
    # number shift_at_body on (counted from its first, 0), feature shift_feature's mean moves
    # by shift_mm in its sheet's plane and along its normal ("": none)
    shift_feature: str = opt("")
    shift_at_body: int = opt(0, lo=0, hi=10**9)
    shift_mm: float = opt(0.3, lo=-10, hi=10)

    def cross_checks(self) -> Iterator[tuple[str, str]]:
        if self.window_s >= self.period_s:
            yield "window_s", "the clamp window must be shorter than period_s"
        elif self.body_s > self.period_s - self.window_s - 2.0:
            yield (
                "body_s",
                "the body's phase must end 1 s before the window (period_s - window_s - 2)",
            )

    @property
    def body_phase_s(self) -> float:
        """The body phase's length [s] (body_s, -1 resolved; 0: none)."""
        if self.body_s >= 0:
            return self.body_s
        return max(self.period_s - self.window_s - 2.0, 0.0)
