"""The simulated line through the real drivers: every device is opened from the URLs the line
exposes (drivers.registry) and checked against the cell's truth. The line runs in virtual time:
where nothing else makes it pass, the test does (`line.clock.advance`), and the times checked
are exact whatever the machine's load."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from app.config import CellConfig
from app.devicecheck import describe_and_probe
from drivers import registry
from drivers.camera import CameraSettings
from drivers.errors import DeviceError
from drivers.galvo import Galvo
from fakes.cell import SimulatedCell
from fakes.line import SimLine, SimLineSetup
from fakes.truth import Knock
from tests.groups import GIGE_CAMERA

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
FULL = CameraSettings(exposure_us=10_000.0, gain_db=0.0, pixel_format="Mono8")

ViewOf = Callable[[SimulatedCell, str], np.ndarray]  # the view_of fixture (conftest)


@pytest.fixture()
def line(line_cell: SimulatedCell) -> Iterator[SimLine]:
    with SimLine(line_cell, SimLineSetup(camera=False)) as sim:
        yield sim


def stripe_columns_px(image: np.ndarray, threshold: float) -> np.ndarray:
    """Per row, the intensity-weighted column of the pixels above threshold (NaN: none)."""
    img = image.astype(np.float64)
    lit = np.where(img > threshold, img, 0.0)
    weight = lit.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cols = (lit * np.arange(img.shape[1])).sum(axis=1) / weight
    return np.where(weight > 0, cols, np.nan)


def stripe_offset_px(a: np.ndarray, b: np.ndarray) -> float:
    """Median column offset b - a of two stripes over the rows both light (the stripe on a
    sphere is an arc: only row by row are two stripes comparable)."""
    both = ~np.isnan(a) & ~np.isnan(b)
    assert both.sum() >= 50, f"stripes share only {both.sum()} rows"
    return float(np.median(b[both] - a[both]))


def command_volts(galvo: Galvo, volts: float) -> None:
    galvo.set_volts(volts)


def test_the_plc_window_opens_and_closes_on_the_sim_clock(line: SimLine) -> None:
    opens, closes = line.window_bounds_s(0)
    assert (opens, closes) == (40.0, 60.0)  # one 20 s window at the end of every minute
    with registry.open_plc(line.urls["plc"], poll_s=0.002) as plc:
        assert not plc.poll().window_open and line.clock.monotonic() == 0.0
        line.clock.advance(opens - 0.25)
        assert not plc.poll().window_open
        line.clock.advance(0.25)  # the PLC's state follows the clock, nothing else
        inputs = plc.poll()
        assert inputs.window_open and inputs.line_running and plc.heartbeat_alive()
        line.clock.advance(closes - opens - 0.25)
        assert plc.poll().window_open
        line.clock.advance(0.25)
        assert not plc.poll().window_open
        assert line.clock.monotonic() == closes


def test_a_joint_move_over_rmi_takes_the_expected_sim_time_and_lands_the_joints(
    line: SimLine, line_cell: SimulatedCell
) -> None:
    target = HOME + np.array([30.0, 10.0, -10.0, 60.0, 20.0, 90.0])
    with registry.open_robot(line.urls["robot"]) as robot:
        robot.set_override_pct(50)
        t0 = line.clock.monotonic()
        reached = robot.move_joints(target, speed_pct=20)
        took_s = line.clock.monotonic() - t0
    speeds = np.array([175, 175, 175, 250, 250, 355.0]) * 0.20 * 0.50
    at_speed_s = float(np.max(np.abs(target - HOME) / speeds))  # J6: 90 / 35.5 s
    assert at_speed_s == pytest.approx(2.535, abs=1e-3)
    # each joint's time to its speed and the settling at the FINE stop (the simulated robot's)
    expected_s = at_speed_s + line.settings.robot_accel_s + line.settings.robot_settle_s
    assert expected_s > at_speed_s + 0.4
    assert line.controller.motion_durations_s == [pytest.approx(expected_s)]
    assert took_s == pytest.approx(expected_s, abs=1e-9)  # the motion's time, and only it
    np.testing.assert_allclose(line_cell.joints_deg(), target, atol=1e-4)
    np.testing.assert_allclose(reached, target, atol=1e-4)


def test_the_tracker_returns_the_true_centres_within_its_noise(
    line: SimLine, line_cell: SimulatedCell
) -> None:
    with registry.open_tracker(line.urls["tracker"]) as tracker:
        assert tracker.targets() == line_cell.target_ids()
        errors = [
            tracker.measure(t).point_mm - line_cell.target_true_mm(t) for t in tracker.targets()
        ]
    e = np.linalg.norm(errors, axis=1)
    sigma_mean_mm = line_cell.settings.tracker_noise_mm / 4.0  # mean of 16 samples per axis
    assert np.all(e < 6 * sigma_mean_mm) and np.all(e > 0.0)


def test_the_geometric_shortcut_is_the_true_centre_plus_noise_and_follows_the_knock(
    cfg: CellConfig, line_cell: SimulatedCell, view_of: ViewOf
) -> None:
    knock = Knock(at_s=3600.0, shift_mm=0.3, tilt_deg=0.05)
    settings = SimLineSetup(camera=False, knock=knock)
    q = view_of(line_cell, "P1")
    p = cfg.spheres_part_mm["P1"]
    noise_mm = line_cell.settings.sensor_noise_mm
    with SimLine(line_cell, settings) as sim:
        line_cell.set_joints_deg(q)
        before = np.mean([sim.geometric_centre("P1") for _ in range(64)], axis=0)
        # the truth where the robot stands (one stop: the joints did not move in between)
        stands = line_cell.attained_deg()
        truth_before = line_cell.centre_in_sensor(stands, p, sim.clock.monotonic())[0]
        sim.clock.advance(3600.0)
        after = np.mean([sim.geometric_centre("P1") for _ in range(64)], axis=0)
        truth_after = line_cell.centre_in_sensor(stands, p, sim.clock.monotonic())[0]
    tol_mm = 6 * noise_mm / 8.0  # mean of 64
    assert np.linalg.norm(before - truth_before) < tol_mm
    assert np.linalg.norm(after - truth_after) < tol_mm
    assert np.linalg.norm(truth_after - truth_before) > 0.2  # the knock, seen by the sensor


def test_a_device_switched_off_is_gone_from_its_url_and_back_there_once_switched_on(
    line_cell: SimulatedCell, tmp_path: Path
) -> None:
    """`stop_device` closes a device's port (the galvo's pty: its stable link is left
    dangling); `start_device` brings it back at the same URL, the drivers reconnecting."""
    setup = SimLineSetup(camera=False, galvo_link=str(tmp_path / "galvo"))
    with SimLine(line_cell, setup) as sim:
        urls = dict(sim.urls)
        assert urls["galvo"] == f"scpi+serial://{tmp_path / 'galvo'}"
        opens = {
            "plc": registry.open_plc,
            "robot": registry.open_robot,
            "tracker": registry.open_tracker,
            "galvo": registry.open_galvo,
        }
        for family, open_device in opens.items():
            sim.stop_device(family)
            assert sim.stopped == {family}
            with pytest.raises(DeviceError):
                open_device(urls[family], timeout_s=1.0).close()
            sim.start_device(family)
            assert not sim.stopped and sim.urls[family] == urls[family]
            with open_device(urls[family], timeout_s=5.0) as device:
                assert describe_and_probe(device)
        sim.inject("plc_heartbeat_loss")
        sim.stop_device("plc")
        sim.start_device("plc")  # a PLC switched on again beats
        with registry.open_plc(urls["plc"], poll_s=0.002) as plc:
            beat = plc.poll().heartbeat
            sim.clock.advance(sim.settings.beat_s)
            assert plc.poll().heartbeat != beat
        with pytest.raises(ValueError, match="no device 'camera'"):
            sim.stop_device("camera")


@GIGE_CAMERA
def test_galvo_via_scpi_moves_the_stripe_the_aravis_camera_streams(
    cfg: CellConfig, line_cell: SimulatedCell, view_of: ViewOf
) -> None:
    q = view_of(line_cell, "P2")
    with (
        SimLine(line_cell, SimLineSetup()) as sim,
        registry.open_robot(sim.urls["robot"]) as robot,
        registry.open_galvo(sim.urls["galvo"]) as galvo,
        registry.open_camera(sim.urls["camera"], settings=FULL, timeout_s=5.0) as camera,
    ):
        robot.move_joints(q, speed_pct=100)
        columns = {}
        for volts in (-0.5, 0.5):
            command_volts(galvo, volts)
            assert sim.dac.volts == pytest.approx(volts, abs=1e-6)  # what the DAC really got
            frame = camera.grab()
            assert frame.image.shape == (966, 1296) and frame.image.dtype == np.uint8
            reference = line_cell.render_frame_v(1296, 966, 10_000.0, 0.0, volts)
            columns[volts] = stripe_columns_px(frame.image, 80)
            expected = stripe_columns_px(reference, 80 / 255)
            assert stripe_offset_px(expected, columns[volts]) == pytest.approx(0.0, abs=1.0)
    assert stripe_offset_px(columns[-0.5], columns[0.5]) > 30.0  # the stripe moved with the mirror


@GIGE_CAMERA
def test_a_camera_region_is_cut_at_its_offsets_and_a_view_without_sphere_is_dark(
    cfg: CellConfig, line_cell: SimulatedCell, view_of: ViewOf
) -> None:
    q = view_of(line_cell, "P3")
    region = CameraSettings(region=(200, 100, 800, 600), pixel_format="Mono8")
    with (
        SimLine(line_cell, SimLineSetup()) as sim,
        registry.open_camera(sim.urls["camera"], settings=region, timeout_s=5.0) as camera,
    ):
        assert camera.sensor_size() == (1296, 966)
        dark = camera.grab().image
        line_cell.set_joints_deg(q)
        frame = camera.grab().image
    assert dark.shape == (600, 800) and dark.max() < 40
    reference = line_cell.render_frame_v(1296, 966, 10_000.0, 0.0, 0.0)[100:700, 200:1000]
    offset = stripe_offset_px(stripe_columns_px(reference, 80 / 255), stripe_columns_px(frame, 80))
    assert offset == pytest.approx(0.0, abs=1.0)


def _fds_and_threads() -> tuple[int, int, int]:
    """Open file descriptors, OS threads and Python threads of this process."""
    fds, tasks = os.listdir("/proc/self/fd"), os.listdir("/proc/self/task")
    return len(fds), len(tasks), threading.active_count()


def _settled_within(limit: tuple[int, int, int], timeout_s: float) -> tuple[int, int, int]:
    """The counts once none exceeds `limit`, or as they are after timeout_s: native threads
    (Aravis's stream and GigE fake threads) end a moment after their owner let them go."""
    deadline = time.monotonic() + timeout_s
    tick = threading.Event()
    while time.monotonic() < deadline:
        now = _fds_and_threads()
        if all(n <= m for n, m in zip(now, limit, strict=True)):
            break
        tick.wait(0.01)
    return now


@GIGE_CAMERA
def test_every_thread_socket_pty_and_the_gige_fake_close_on_exit(
    line_cell: SimulatedCell,
) -> None:
    def one_shift() -> None:
        with (
            SimLine(line_cell, SimLineSetup()) as sim,
            registry.open_plc(sim.urls["plc"]) as plc,
            registry.open_robot(sim.urls["robot"]) as robot,
            registry.open_galvo(sim.urls["galvo"]) as galvo,
            registry.open_tracker(sim.urls["tracker"]) as tracker,
            registry.open_camera(sim.urls["camera"], timeout_s=5.0) as camera,
        ):
            plc.poll()
            robot.joints_deg()
            command_volts(galvo, 0.1)
            tracker.targets()
            camera.grab()

    one_shift()  # Aravis and pymodbus start their own lasting helpers on first use
    before = _fds_and_threads()
    for _ in range(2):
        one_shift()
        assert threading.active_count() <= before[2]  # Python threads: joined by close()
    after = _settled_within(before, 5.0)
    assert all(n <= m for n, m in zip(after, before, strict=True)), (after, before)


def test_the_cell_files_simline_defaults_are_the_simulated_lines() -> None:
    """[simline] (app.config.line) declares the simulated line's settings for the cell file;
    fakes/ cannot import app/, so its SimLineSetup and Warmup repeat the defaults, pinned. (Its
    `scale` is the pace of the runs a person watches; the line itself defaults to unpaced.)"""
    from app.config.line import SimLineSection
    from fakes.truth import Warmup

    s, setup, warm = SimLineSection(), SimLineSetup(), Warmup()
    assert (s.period_s, s.window_s, s.beat_s, s.n_validation) == (
        setup.period_s,
        setup.window_s,
        setup.beat_s,
        setup.n_validation,
    )
    assert (s.camera_readout_s, s.galvo_settle_s) == (setup.camera_readout_s, setup.galvo_settle_s)
    assert setup.scale is None and setup.clock == "virtual"
    assert (s.warmup_k, s.warmup_tau_s, s.warmup_start_s) == (warm.rise_k, warm.tau_s, warm.start_s)


@GIGE_CAMERA
def test_a_rendered_sweep_passes_its_exposures_read_outs_and_settling(
    line_cell: SimulatedCell,
) -> None:
    """The peers charge what they simulate: the galvo's settling per command, the camera's
    exposure and read-out per frame; nothing else moves the line's time."""
    setup = SimLineSetup()
    with (
        SimLine(line_cell, setup) as sim,
        registry.open_galvo(sim.urls["galvo"]) as galvo,
        registry.open_camera(sim.urls["camera"], settings=FULL, timeout_s=5.0) as camera,
    ):
        t0 = sim.clock.monotonic()
        for volts in (-0.5, 0.0, 0.5):
            command_volts(galvo, volts)
            camera.grab()
        took_s = sim.clock.monotonic() - t0
    frame_s = FULL.exposure_us * 1e-6 + setup.camera_readout_s
    assert took_s == pytest.approx(3 * (setup.galvo_settle_s + frame_s), abs=1e-9)
