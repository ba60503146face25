"""The true robot repeats like a real one (issue 38 item 9): every stop of the simulated robot is
off by a new pose error derived from the FANUC M-710iC/50 data sheet's pose repeatability (ISO
9283 RP +-0.07 mm, `fakes.truth.Repeatability`), on the geometric and the rendered path and in
the truth's validation measurements; 0 gives an exact world.

The statistical checks are seeded: N stops at one configuration, their sphere centres' RMS
spread per axis against the one the joint model predicts there (its Jacobian times the joint
sigma), within 15 % (the mean square of 3 N = 900 numbers has a relative standard deviation of
about 5 %: 15 % is 3 of them)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.config import CellConfig
from app.config.cell import SimulationSection
from app.line.estimate import sphere_sigma_mm
from app.line.schedule import Schedule
from app.line.settings import from_cell
from app.sim.cell import make_cell, render_and_measure
from fakes.cell import SimulatedCell
from fakes.cell_spec import SimSettings
from fakes.line_truth import LineTruth, validation_positions
from fakes.render_sensor import TrueSensor
from fakes.truth import (
    M710IC50_RP_MM,
    RP_REFERENCE_DEG,
    Repeatability,
    TrueRobot,
    controller_offsets_deg,
)
from tests.sim.conftest import ViewOf
from vision.sensor_model import default_sensor_model

N_STOPS = 300
HOME_DEG = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])


def _rp(points_mm: np.ndarray) -> float:
    """ISO 9283 RP of attained positions (n, 3): mean + 3 std of their distance from the
    barycentre."""
    d = np.linalg.norm(points_mm - points_mm.mean(axis=0), axis=1)
    return float(d.mean() + 3.0 * d.std())


def _predicted_rms_mm(cell: SimulatedCell, q_deg: np.ndarray, p_part_mm: np.ndarray) -> float:
    """The RMS per axis of the sphere centre in the sensor frame that the joint model predicts
    at q_deg: sqrt(trace(J J^T) / 3) sigma_q, J the centre's Jacobian in the physical joints."""
    h = 1e-6
    du = controller_offsets_deg(np.vstack([h * np.eye(6), -h * np.eye(6)]))
    c = cell.centre_in_sensor(q_deg + du, p_part_mm, 0.0)
    J = (c[:6] - c[6:]) / (2 * h)
    return float(np.sqrt(np.sum(J**2) / 3.0) * cell.repeatability.joint_sigma_rad)


def _spread_mm(centres_mm: np.ndarray) -> float:
    """The RMS per axis of centres (n, 3) about their mean."""
    return float(np.sqrt(np.mean((centres_mm - centres_mm.mean(axis=0)) ** 2)))


@pytest.fixture()
def exact_sensor_cell(cfg: CellConfig, true_sensor: TrueSensor) -> SimulatedCell:
    """The default cell (RP 0.07 mm) with a noise-free geometric sensor: what varies between
    two visits is the robot alone."""
    return make_cell(cfg, seed=11, sensor=true_sensor, sensor_noise_mm=0.0)


def test_the_data_sheet_figure_is_the_flange_s_rp_at_the_reference_pose() -> None:
    """The joint sigma derived from RP 0.07 mm gives the flange an RP of 0.07 mm at the
    reference pose, measured the way ISO 9283 measures it (stops, barycentre, mean + 3 std)."""
    rep = Repeatability()
    assert rep.rp_mm == M710IC50_RP_MM == 0.07
    assert 1e-5 < rep.joint_sigma_rad < 3e-5  # a few arcsec per joint
    dq = rep.draw_deg(np.random.default_rng(1), 20_000)
    flange = TrueRobot().T_world_tool0(np.asarray(RP_REFERENCE_DEG) + dq)[:, :3, 3]
    assert _rp(flange) == pytest.approx(0.07, rel=0.03)
    assert Repeatability(0.0).joint_sigma_rad == 0.0
    with pytest.raises(ValueError):
        Repeatability(-0.01)


def test_the_geometric_path_stops_anew_at_every_measurement(
    cfg: CellConfig, exact_sensor_cell: SimulatedCell, view_of: ViewOf
) -> None:
    """The same configuration measured again is a new stop: the centres differ by the robot's
    repeatability at that view, about the figure's sigma per axis (RP / 3.6 = 19 um at the
    flange, more at the sphere 130 mm in front of the sensor), and their RP is about the data
    sheet's."""
    cell, p = exact_sensor_cell, cfg.spheres_part_mm["P1"]
    q = view_of(cell, "P1")
    c = np.array([cell.measure_point(q, p) for _ in range(N_STOPS)])
    assert np.all(np.linalg.norm(c[1:] - c[:-1], axis=1) > 0)  # never the same stop twice
    predicted = _predicted_rms_mm(cell, q, p)
    assert 0.012 < predicted < 0.035
    assert _spread_mm(c) == pytest.approx(predicted, rel=0.15)
    # the true centre from the commanded pose is the stops' mean, within its standard error
    truth = cell.centre_in_sensor(q, p)[0]
    assert np.all(np.abs(c.mean(axis=0) - truth) < 6 * predicted / np.sqrt(N_STOPS))
    assert 0.06 < _rp(c) < 0.14


def test_the_world_path_keeps_one_stop_per_move(
    cfg: CellConfig, exact_sensor_cell: SimulatedCell, view_of: ViewOf
) -> None:
    """Through the device fakes' World (set_joints_deg, then measure_target or the camera):
    every measurement at one stop sees the same pose (the frames of a sweep), a move away and
    back is a new stop, and the stops spread as the geometric path's do."""
    cell, p = exact_sensor_cell, cfg.spheres_part_mm["P1"]
    q = view_of(cell, "P1")
    centres = []
    for _ in range(N_STOPS):
        cell.set_joints_deg(q)
        first = cell.measure_target("P1")
        cell.set_joints_deg(q)  # a move to where it stands: no motion, the same stop
        assert np.array_equal(cell.measure_target("P1"), first)
        stands = cell.attained_deg()
        np.testing.assert_allclose(cell.centre_in_sensor(stands, p)[0], first, atol=1e-12)
        assert np.abs(stands - q).max() > 0
        centres.append(first)
        cell.set_joints_deg(HOME_DEG)  # away (nothing measured there) and back
    c = np.array(centres)
    assert _spread_mm(c) == pytest.approx(_predicted_rms_mm(cell, q, p), rel=0.15)


def test_the_rendered_path_sweeps_from_where_the_robot_stands(
    cfg: CellConfig, exact_sensor_cell: SimulatedCell, view_of: ViewOf
) -> None:
    """A sweep's true centre (what the renderer draws) is that of a new stop each time, spread
    as the geometric path's; two sweeps of the same view measured by the vision differ by the
    difference of their stops, within the vision's few um."""
    cell, p = exact_sensor_cell, cfg.spheres_part_mm["P1"]
    q = view_of(cell, "P1")
    jobs = [cell.sweep_job(q, p) for _ in range(N_STOPS)]
    c = np.array([j.c_sensor_mm for j in jobs])
    assert _spread_mm(c) == pytest.approx(_predicted_rms_mm(cell, q, p), rel=0.15)
    a, b = (render_and_measure(j, cell.sensor, default_sensor_model()) for j in jobs[:2])
    assert a.c_sensor_mm is not None and b.c_sensor_mm is not None
    seen, true = b.c_sensor_mm - a.c_sensor_mm, jobs[1].c_sensor_mm - jobs[0].c_sensor_mm
    assert np.linalg.norm(true) > 0.01  # two stops, tens of um apart
    assert np.linalg.norm(seen - true) < 0.005  # the vision's own error: a few um


def test_the_truth_s_validation_measurements_are_moves(
    cfg: CellConfig, exact_sensor_cell: SimulatedCell
) -> None:
    """The truth's validation centres (what `EndToEndTruth` maps on both paths) are each seen
    from a stop of its own: the same time gives the same stops, another time new ones, spread
    about the commanded pose's centres by the robot's repeatability."""
    cell = exact_sensor_cell
    v = validation_positions(cell, 60, np.random.default_rng(3))
    truth = LineTruth(cell, v)
    exact = cell.centre_in_sensor(v.q_deg, v.p_part_mm, 0.0)
    at_1 = truth.validation_centres_sensor_mm(1.0)
    np.testing.assert_array_equal(truth.validation_centres_sensor_mm(1.0), at_1)
    at_2 = truth.validation_centres_sensor_mm(2.0)
    rms_1 = float(np.sqrt(np.mean((at_1 - exact) ** 2)))
    rms_12 = float(np.sqrt(np.mean((at_2 - at_1) ** 2)))
    per_position = [
        _predicted_rms_mm(cell, q, p) for q, p in zip(v.q_deg, v.p_part_mm, strict=True)
    ]
    predicted = float(np.sqrt(np.mean(np.square(per_position))))
    assert rms_1 == pytest.approx(predicted, rel=0.2)  # 180 numbers: 3 std of 10 %, 20 %
    assert rms_12 == pytest.approx(np.sqrt(2.0) * predicted, rel=0.2)


def test_repeatability_0_is_an_exact_world_on_every_path(
    cfg: CellConfig, true_sensor: TrueSensor, view_of: ViewOf
) -> None:
    cell = make_cell(cfg, seed=11, sensor=true_sensor, sensor_noise_mm=0.0, repeatability_mm=0.0)
    p = cfg.spheres_part_mm["P3"]
    q = view_of(cell, "P3")
    truth = cell.centre_in_sensor(q, p)[0]
    for _ in range(3):
        np.testing.assert_array_equal(cell.measure_point(q, p), truth)
        np.testing.assert_array_equal(cell.sweep_job(q, p).c_sensor_mm, truth)
        cell.set_joints_deg(q)
        np.testing.assert_array_equal(cell.attained_deg(), q)
        np.testing.assert_array_equal(cell.measure_target("P3"), truth)
        cell.set_joints_deg(HOME_DEG)
    v = validation_positions(cell, 10, np.random.default_rng(3))
    centres = LineTruth(cell, v).validation_centres_sensor_mm
    np.testing.assert_array_equal(centres(1.0), centres(2.0))
    np.testing.assert_array_equal(centres(1.0), cell.centre_in_sensor(v.q_deg, v.p_part_mm, 1.0))


def test_a_seed_gives_the_same_stops_and_another_seed_others(
    cfg: CellConfig, true_sensor: TrueSensor, view_of: ViewOf
) -> None:
    """Deterministic per seed (no global random state); a stop's error depends on its joints
    and the stops there before, not on the moves elsewhere in between."""
    p = cfg.spheres_part_mm["P2"]

    def cell(seed: int) -> SimulatedCell:
        return make_cell(cfg, seed=seed, sensor=true_sensor, sensor_noise_mm=0.0)

    q = view_of(cell(5), "P2")
    a, b = cell(5), cell(5)
    first = [a.measure_point(q, p) for _ in range(3)]
    b.new_stop_deg(HOME_DEG)  # stops elsewhere first
    b.new_stop_deg(q + 1.0)
    np.testing.assert_array_equal([b.measure_point(q, p) for _ in range(3)], first)
    assert not np.array_equal(cell(6).measure_point(q, p), first[0])


def test_the_cell_file_s_simulation_defaults_are_the_simulated_cell_s() -> None:
    """[simulation] declares the cell file's keys; their defaults are SimSettings' (the
    repeatability's figure and the geometric sensor's own noise are justified there), and
    make_cell passes each key on."""
    section, settings = SimulationSection(), SimSettings()
    world = {f.name for f in dataclasses.fields(settings)}
    for f in dataclasses.fields(section):
        if f.name == "geometric":  # how the cell is measured, not the world: not SimSettings'
            continue
        assert f.name in world and getattr(section, f.name) == getattr(settings, f.name), f.name
    assert settings.repeatability_mm == M710IC50_RP_MM
    assert settings.sensor_noise_mm == 0.005


def test_make_cell_passes_the_repeatability_on(cfg: CellConfig) -> None:
    sim = dataclasses.replace(cfg.simulation, repeatability_mm=0.02, sensor_noise_mm=0.001)
    cell = make_cell(dataclasses.replace(cfg, simulation=sim))
    assert cell.repeatability.rp_mm == 0.02 and cell.settings.sensor_noise_mm == 0.001


def test_the_acceptance_states_the_robot_s_share_of_sd_as_the_true_robot_makes_it(
    cfg: CellConfig, exact_sensor_cell: SimulatedCell
) -> None:
    """The sensor acceptance's SD is judged against the robot's motion; its stated share of the
    robot (`robot_spacing_mm`, calib's joint model from the data sheet's RP) is the 95 %
    quantile of the largest |SD| that the simulated true robot's stops give a perfect sensor at
    the 9 views: over 200 seeded runs of the 9 stops, 3-10 % of them beyond it (5 % expected;
    200 runs: a standard error of 1.5 %), and with RP 0 no share."""
    from app.commission.acceptance import robot_spacing_mm, views, volume_positions
    from calib.datasheet import POSE_REPEATABILITY_MM
    from vision.acceptance import spacing_errors

    assert POSE_REPEATABILITY_MM == M710IC50_RP_MM  # the plant's figure is the world's
    cell = exact_sensor_cell
    model = cfg.model()
    x = model.nominal_x()
    p = np.asarray(cfg.spheres_part_mm["P1"])
    qs = views(model, x, p, volume_positions(cfg.sensor), np.random.default_rng([0, 29]))
    assert len(qs) == 9
    share = robot_spacing_mm(model, x, qs, p, cfg.robot.repeatability_mm)
    assert 2 * cfg.sensor.max_sd_mm < share < 0.2  # several times the sensor's own limit
    assert robot_spacing_mm(model, x, qs, p, 0.0) == 0.0
    # the true robot's stops seen by a perfect sensor, judged against the commanded poses of
    # the true robot (what a calibrated model's short moves are, to a few um)
    T_true = cell.T_part_sensor(qs)
    worst = [
        np.abs(spacing_errors(np.array([cell.measure_point(q, p) for q in qs]), T_true)[1]).max()
        for _ in range(200)
    ]
    assert 0.03 <= np.mean(np.array(worst) > share) <= 0.10


def test_the_noise_the_estimator_gives_a_sphere_measurement_is_the_simulated_cells(
    cfg: CellConfig, line_cell: SimulatedCell, view_of: ViewOf
) -> None:
    """A sphere measurement's own noise, as the service derives it at its start (issue 50 item
    3: the sensor's and the robot's repeatability through the model; app.line.estimate), is
    the spread the simulated cell gives N stops at each of four views (its sensor's noise and
    its robot's, which the service knows only from the data sheet), within 15 %. The hand-set
    0.02 mm it replaces was 20 % short, and the statement's unmodelled term held the rest."""
    model = cfg.model()
    spheres = {t: cfg.spheres_part_mm[t] for t in ("P1", "P2", "P3", "P4")}
    q = {t: view_of(line_cell, t) for t in spheres}
    settings = dataclasses.replace(
        from_cell(cfg),
        repeatability_mm=float(cfg.simulation.repeatability_mm),
        sensor_centre_sd_mm=float(cfg.simulation.sensor_noise_mm),
    )
    schedule = Schedule({t: q[t][None] for t in spheres}, settings.line)
    derived = sphere_sigma_mm(settings, model, model.nominal_x(), schedule, spheres)
    spread = [
        np.mean((c - c.mean(axis=0)) ** 2)
        for c in (
            np.array([line_cell.measure_point(q[t], p) for _ in range(N_STOPS // 2)])
            for t, p in spheres.items()
        )
    ]
    assert derived == pytest.approx(float(np.sqrt(np.mean(spread))), rel=0.15)
    assert derived > 0.022
    # a value set in the cell file is taken as it is
    fixed = dataclasses.replace(
        settings, recalib=dataclasses.replace(settings.recalib, jump_sigma_mm=0.03)
    )
    assert sphere_sigma_mm(fixed, model, model.nominal_x(), schedule, spheres) == 0.03
